#!/bin/bash
# The third arm of the learning-rate A/B: lr 0.0005, run.sh's command, seed and thread count, started after the
# other two had finished, on one thread while the other core ran the test suite.
exec env LRS=0.0005 "$(dirname "$0")/run.sh"
