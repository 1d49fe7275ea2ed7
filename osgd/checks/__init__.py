"""The checks stage: simulated grasp trials in pybullet."""
