"""osgd: builds task-oriented grasping datasets of stacked objects.

Data flows through five stages, one sub-package each::

    osgd.models  -> osgd.grasps -> osgd.checks -> osgd.scenes -> osgd.samples
"""

import os as _os
import sys as _sys

__version__ = "0.1.0"

#: numpy kernels left out of its run-time dispatch (see below).
PORTABLE_NUMPY_DISABLED_FEATURES = (
    "X86_V4 AVX512_ICL AVX512_SPR "  # numpy >= 2.3 names
    "AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL"  # older names
)

# Byte-identical shards across machines: numpy picks its SIMD kernels when it
# is imported, and its AVX-512 ones (sin, cos, exp, log, arccos...) round
# differently from its AVX2 and scalar ones. One random orientation off in its
# last bit gives another pile after a second of physics, so a dataset built on
# an AVX-512 machine differed from one built on an AVX2 machine. Leaving the
# AVX-512 kernels out (about the same speed for this code) makes the two agree;
# osgd.raycast does the same for embree. This only works before numpy is first
# imported, so it is done here, and only then: a process that imported numpy
# first keeps its kernels, and so do the workers it starts (they inherit the
# environment), so a run stays consistent with itself. A user's own
# NPY_DISABLE_CPU_FEATURES wins; OSGD_NATIVE_SIMD=1 turns this off.
if "numpy" not in _sys.modules and _os.environ.get("OSGD_NATIVE_SIMD", "") != "1":
    _os.environ.setdefault("NPY_DISABLE_CPU_FEATURES", PORTABLE_NUMPY_DISABLED_FEATURES)
