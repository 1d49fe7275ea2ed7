"""The kernels osgd pins for the same shards on any x86-64 (osgd/kernels.py)."""

from __future__ import annotations

from osgd.kernels import PORTABLE_OPENBLAS_CORETYPE, cpu_flags, pin_kernels, portable_settings

V3 = frozenset({"sse2", "avx", "avx2", "fma", "avx512f"})
V2 = frozenset({"sse2", "sse4_2", "popcnt", "avx"})


def test_openblas_is_pinned_only_where_its_kernels_run() -> None:
    assert portable_settings(V3, "x86_64")["OPENBLAS_CORETYPE"] == PORTABLE_OPENBLAS_CORETYPE
    assert "OPENBLAS_CORETYPE" not in portable_settings(V2, "x86_64")
    assert portable_settings(V2, "x86_64")["OPENBLAS_NUM_THREADS"] == "1"
    assert portable_settings(V3, "aarch64") == {}


def test_cpu_flags_reads_the_flags_line() -> None:
    assert cpu_flags("processor\t: 0\nflags\t\t: fpu avx2 fma\n") == {"fpu", "avx2", "fma"}
    assert cpu_flags("processor\t: 0\n") == frozenset()


def test_a_users_setting_wins_and_native_simd_turns_pinning_off() -> None:
    environ = {"OPENBLAS_CORETYPE": "SkylakeX"}
    applied = pin_kernels(environ)
    assert environ["OPENBLAS_CORETYPE"] == "SkylakeX"
    assert "OPENBLAS_CORETYPE" not in applied
    assert pin_kernels({"OSGD_NATIVE_SIMD": "1"}) == {}
