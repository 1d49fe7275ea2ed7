#!/usr/bin/env bash
# Issue #16, item 4: the checks' approach failures on scan stand-ins brought as users' meshes, by collision shape.
# make_scans.py writes a fork, a wrench and a pliers (procedural tools turned, remeshed to 2 mm edges and noised by
# 0.2 mm, in millimetres) and the same tools clean, each with a sidecar of category and length alone; then annotate
# and check run on them with the `fast` preset (what a user's mesh got before the `scan` preset), the `scan` preset
# (what `auto` gives a user's mesh), and the `scan` preset with the approach swept against the mesh
# (`checks.approach_geometry = "mesh"`, as pipelines/osgd.toml does). Run from the repository root:
#   lab/results/decomposition/scan-checks/run.sh [WORK_DIR]      # writes WORK_DIR/<config>.log and summary.txt
set -euo pipefail
cd "$(dirname "$0")/../../../.."
WORK=${1:-/tmp/scan-checks}
OSGD=${OSGD:-.venv/bin/osgd}
PYTHON=${PYTHON:-.venv/bin/python}
mkdir -p "$WORK"
$PYTHON lab/results/decomposition/scan-checks/make_scans.py "$WORK/meshes" fork,wrench,pliers
for config in fast:hulls scan:hulls scan:mesh; do
    preset=${config%:*} approach=${config#*:}
    cat > "$WORK/$preset-$approach.toml" <<TOML
[pipeline]
name = "scan-checks-$preset-$approach"
seed = 0

[models]
sources = ["user"]
user_dir = "$WORK/meshes"
decomposition = "$preset"

[checks]
approach_geometry = "$approach"
TOML
    { $OSGD --data-dir "$WORK/data" --workers 2 annotate -c "$WORK/$preset-$approach.toml" &&
      $OSGD --data-dir "$WORK/data" --workers 2 check -c "$WORK/$preset-$approach.toml"; } > "$WORK/$preset-$approach.log" 2>&1
done
$PYTHON lab/results/decomposition/scan-checks/approach_failures.py "$WORK/data" \
    scan-checks-fast-hulls scan-checks-scan-hulls scan-checks-scan-mesh | tee "$WORK/summary.txt"
