"""togcrf: the TOG and TOG-CRFs task-oriented grasp detectors, trained on osgd shards.

A lean package: it reads ``samples`` shards and needs torch, torchvision,
pyarrow, numpy and OpenCV, never the generator's physics or mesh libraries,
except ``togcrf.robot`` (the robot experiment in simulation), which runs them.
"""

__version__ = "0.1.0"
