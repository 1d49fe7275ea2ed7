S="taskset -c 1 env OPENBLAS_NUM_THREADS=1 .venv/bin/python /tmp/c73/subset.py"
$S --objkw '{"maximal_coordinates": true}' --out /tmp/c73/maximal.json
$S --objdyn '{"contactProcessingThreshold": 0.0}' --out /tmp/c73/cpt0.json
$S --objkw '{"max_hull_vertices": 64}' --out /tmp/c73/hull64.json
$S --engine '{"solverResidualThreshold": 1e-3}' --out /tmp/c73/resid3.json
