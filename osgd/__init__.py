"""osgd: builds task-oriented grasping datasets of stacked objects.

Data flows through five stages, one sub-package each::

    osgd.models  -> osgd.grasps -> osgd.checks -> osgd.scenes -> osgd.samples

Importing osgd changes nothing in the process: the entry points (``osgd``,
``python -m osgd``) pin the processor-dependent numerical kernels before
numpy loads, so that shards are the same on any x86-64 processor
(:mod:`osgd.kernels`); a program that runs the stages itself calls
:func:`osgd.kernels.pin_kernels` first to build the same bytes.
"""

__version__ = "0.1.0"
