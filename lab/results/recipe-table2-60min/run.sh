#!/bin/bash
# Table II of the CPU recipe at its own budget, 60 minutes of training steps per model on both cores of a
# 2-core AMD EPYC (issue #15), put together row by row from runs committed in their own folders, each with
# the command that made it (commands.txt there):
#   FCGN + Task  seed 0      ../recipe-2cores-fcgn-2026-11-28/       (AVX-512 EPYC, 2026-11-28)
#   TOG          seeds 0, 1  ../recipe-2cores-2026-11-27/, ../recipe-2cores-seed1-2026-11-27/   (AVX2 EPYC)
#   TOG-CRFs omega  seed 0   ../recipe-2cores-crfs-omega-2026-11-28/  (AVX-512 EPYC, 2026-11-28)
#   TOG-CRFs mu     seed 0   ../recipe-2cores-crfs-mu-2026-11-28/     (AVX-512 EPYC, 2026-11-28)
#   TOG-CRFs     seeds 0, 1  ../recipe-2cores-crfs-2026-11-28/, ../recipe-2cores-crfs-seed1-2026-11-28/ (AVX2 EPYC)
# Each row's seed comes from the MODEL-config.json beside its MODEL-eval*.json.
set -e
cd "$(dirname "$0")/.."
TOGCRF=${TOGCRF:-../../.venv/bin/togcrf}
for suffix in "" -lab; do
    seed0=(recipe-2cores-fcgn-2026-11-28/fcgn-task-eval$suffix.json
           recipe-2cores-2026-11-27/tog-eval$suffix.json
           recipe-2cores-crfs-omega-2026-11-28/tog-crfs-omega-eval$suffix.json
           recipe-2cores-crfs-mu-2026-11-28/tog-crfs-mu-eval$suffix.json
           recipe-2cores-crfs-2026-11-28/tog-crfs-eval$suffix.json)
    seed1=(recipe-2cores-seed1-2026-11-27/tog-eval$suffix.json
           recipe-2cores-crfs-seed1-2026-11-28/tog-crfs-eval$suffix.json)
    $TOGCRF table "${seed0[@]}" --out recipe-table2-60min/table2$suffix.json > recipe-table2-60min/table2$suffix.txt
    $TOGCRF table "${seed0[@]}" "${seed1[@]}" --mean --out recipe-table2-60min/means$suffix.json \
        > recipe-table2-60min/means$suffix.txt
done
