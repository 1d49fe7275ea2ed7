S="taskset -c 1 env OPENBLAS_NUM_THREADS=1 .venv/bin/python /tmp/c73/subset.py"
$S --set solver_iterations=50 --out /tmp/c73/it50.json
$S --set solver_iterations=30 --out /tmp/c73/it30.json
$S --set timestep=0.008333333333333333 --out /tmp/c73/ts120.json
$S --set timestep=0.008333333333333333 --set solver_iterations=50 --out /tmp/c73/ts120it50.json
$S --set timestep=0.00625 --out /tmp/c73/ts160.json
