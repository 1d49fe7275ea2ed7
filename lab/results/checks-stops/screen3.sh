S="taskset -c 1 env OPENBLAS_NUM_THREADS=1 .venv/bin/python /tmp/c73/subset.py --variants annotated,off_centre,turned,narrow --every-grasp 6"
$S --code /tmp/c73/old --out /tmp/c73/v_old.json
$S --out /tmp/c73/v_new.json
$S --set hold_still_duration=0 --out /tmp/c73/v_new_nohold.json
