"""osgd: builds task-oriented grasping datasets of stacked objects.

Data flows through five stages, one sub-package each::

    osgd.models  -> osgd.grasps -> osgd.checks -> osgd.scenes -> osgd.samples
"""

__version__ = "0.1.0"
