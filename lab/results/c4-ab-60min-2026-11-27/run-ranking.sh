#!/bin/bash
# The top-1 ranking term (model option grasp_ranking_weight 1.0) against the recipe (C4, 160 px: "c4-160"),
# TOG, seed 1, one thread each, side by side, 60 minutes each: runs/ranking-ab/{c4-160,c4-160-rank}. The c4-160
# arm repeats the command of the A/B's c4-160 arm of the session before, in this session.
exec env ARMS="c4-160 c4-160-rank" OUT=runs/ranking-ab "$(dirname "$0")/run.sh"
