"""The scenes stage: stacks of 3-6 objects dropped in pybullet."""
