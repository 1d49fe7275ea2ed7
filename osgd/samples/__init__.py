"""The samples stage: noisy depth images with boxes and task-labelled grasp rectangles."""
