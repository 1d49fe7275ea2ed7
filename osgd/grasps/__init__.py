"""The grasps stage: 6-DoF parallel-jaw grasps with task labels."""
