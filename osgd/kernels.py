"""The processor-dependent kernels osgd pins, so that shards are the same on any x86-64.

Three libraries pick their kernels by processor when they load and round
differently from one kernel to another (docs/architecture.md, "Across
machines"):

- **OpenBLAS** (numpy's and scipy's BLAS and LAPACK): its ``SkylakeX`` kernels
  on an AVX-512 processor and its ``Haswell`` / ``Zen`` kernels on an AVX2 one
  give other last bits in ``eigh`` (the principal axes of inertia every
  pybullet body is built with), ``norm``, ``dot`` and ``@``. That alone makes
  shards differ between an AVX-512 and an AVX2 processor.
  :func:`pin_kernels` sets ``OPENBLAS_CORETYPE=Haswell`` on every processor
  that has AVX2 and FMA (x86-64-v3: Intel since Haswell, AMD since Zen), and
  ``OPENBLAS_NUM_THREADS=1`` so that no reduction is split by core count.
- **numpy** itself: its AVX-512 kernels of sin, cos, exp, log, arccos... round
  differently from its AVX2 and baseline ones; they are left out of its
  dispatch through ``NPY_DISABLE_CPU_FEATURES``.
- **embree**: its float32 hit distances; :mod:`osgd.raycast` keeps embree's
  answer to *which* triangle and computes *where* again in float64.

Environment variables only act before the library is loaded, so
:func:`pin_kernels` runs in the entry points before anything imports numpy:
``osgd`` and ``python -m osgd`` (:mod:`osgd.__main__`) and the test suite's
``conftest.py``. Worker processes inherit the environment. Importing
``osgd`` changes nothing: a program that drives the stages itself calls
:func:`pin_kernels` first (or sets the variables) to build the same bytes.

A user's own setting of any of these variables wins, and ``OSGD_NATIVE_SIMD=1``
turns the pinning off (each library then picks the fastest kernels for the
processor, and shards may differ in their last bits from other machines').

What remains processor-dependent (not pinned): on an x86-64 processor without
AVX2 and FMA (x86-64-v2), OpenBLAS's and glibc libm's generic kernels round
differently from the FMA ones, and the chaotic physics of the checks and
scenes stages turns that into other trials and piles. The golden test
accepts that as "the same dataset" under documented tolerances
(``tests/test_golden.py``).
"""

from __future__ import annotations

import os
import platform
import sys
from collections.abc import MutableMapping

#: numpy kernels left out of its run-time dispatch.
PORTABLE_NUMPY_DISABLED_FEATURES = (
    "X86_V4 AVX512_ICL AVX512_SPR "  # numpy >= 2.3 names
    "AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL"  # older names
)

#: The OpenBLAS kernel family every x86-64-v3 processor runs (what OpenBLAS
#: itself picks on AVX2 processors: Haswell, Zen 1 to 3).
PORTABLE_OPENBLAS_CORETYPE = "Haswell"

#: Processor features the pinned OpenBLAS kernels need (``/proc/cpuinfo`` names).
_OPENBLAS_CORETYPE_NEEDS = frozenset({"avx2", "fma"})


def cpu_flags(cpuinfo: str | None = None) -> frozenset[str]:
    """The processor's feature flags as Linux lists them (empty elsewhere).

    Parameters
    ----------
    cpuinfo : str, optional
        Text of ``/proc/cpuinfo``; read from the system when omitted.
    """
    if cpuinfo is None:
        try:
            with open("/proc/cpuinfo", encoding="ascii", errors="replace") as handle:
                cpuinfo = handle.read()
        except OSError:
            return frozenset()
    for line in cpuinfo.splitlines():
        name, _, value = line.partition(":")
        if name.strip() == "flags":
            return frozenset(value.split())
    return frozenset()


def portable_settings(flags: frozenset[str] | None = None, machine: str | None = None) -> dict[str, str]:
    """The environment variables that pin the kernels on this processor.

    Parameters
    ----------
    flags : frozenset of str, optional
        Processor flags (:func:`cpu_flags` by default).
    machine : str, optional
        ``platform.machine()`` by default.
    """
    machine = platform.machine() if machine is None else machine
    if machine.lower() not in {"x86_64", "amd64"}:
        return {}
    flags = cpu_flags() if flags is None else flags
    settings = {"NPY_DISABLE_CPU_FEATURES": PORTABLE_NUMPY_DISABLED_FEATURES, "OPENBLAS_NUM_THREADS": "1"}
    if _OPENBLAS_CORETYPE_NEEDS <= flags:
        settings["OPENBLAS_CORETYPE"] = PORTABLE_OPENBLAS_CORETYPE
    return settings


def pin_kernels(environ: MutableMapping[str, str] | None = None) -> dict[str, str]:
    """Pin the processor-dependent kernels (module text) in ``environ``.

    Call it before numpy is imported; worker processes inherit it. Variables
    already set are kept; nothing is set when ``OSGD_NATIVE_SIMD=1``.

    Parameters
    ----------
    environ : mutable mapping, optional
        ``os.environ`` by default.

    Returns
    -------
    dict of str to str
        The variables this call set.
    """
    environ = os.environ if environ is None else environ
    if environ.get("OSGD_NATIVE_SIMD", "") == "1":
        return {}
    if environ is os.environ and "numpy" in sys.modules:
        # Too late for this process (its kernels are chosen); its workers still
        # inherit the settings, and a process must stay consistent with itself.
        return {}
    applied = {}
    for name, value in portable_settings().items():
        if name not in environ:
            environ[name] = value
            applied[name] = value
    return applied
