#!/bin/bash
# The checks on scan stand-ins with the scan preset on every face (scan_max_faces = 0, the preset before
# simplification) and simplified (the default), each with the approach swept against hulls and against the mesh.
set -euo pipefail
cd /tmp/scanwt
export PYTHONPATH=/tmp/scanwt PYTHONHASHSEED=0
WORK=/tmp/scan-checks-new
PY=/work/main/.venv/bin/python
mkdir -p $WORK
taskset -c 0 $PY lab/results/decomposition/scan-checks/make_scans.py $WORK/meshes fork,wrench,pliers
for config in whole:hulls whole:mesh simplified:hulls simplified:mesh; do
  faces=${config%:*} approach=${config#*:}
  max=$([ $faces = whole ] && echo 0 || echo 5000)
  cat > $WORK/$faces-$approach.toml <<TOML
[pipeline]
name = "scan-checks-$faces-$approach"
seed = 0

[models]
sources = ["user"]
user_dir = "$WORK/meshes"
decomposition = "scan"
scan_max_faces = $max

[checks]
approach_geometry = "$approach"
TOML
  start=$(date +%s)
  { taskset -c 0 $PY -m osgd --data-dir $WORK/data --workers 1 annotate -c $WORK/$faces-$approach.toml &&
    taskset -c 0 $PY -m osgd --data-dir $WORK/data --workers 1 check -c $WORK/$faces-$approach.toml; } > $WORK/$faces-$approach.log 2>&1
  echo "$config $(( $(date +%s) - start )) s" >> $WORK/times.txt
done
$PY lab/results/decomposition/scan-checks/approach_failures.py $WORK/data \
    scan-checks-whole-hulls scan-checks-whole-mesh scan-checks-simplified-hulls scan-checks-simplified-mesh | tee $WORK/summary.txt
