#!/bin/bash
# TOG-CRFs with the recipe adopted from this A/B (the "c4-160" arm), seed 1, one thread, to pair with the
# arm's TOG for the CRF question: runs/c4-ab-60min/c4-160-crfs.
exec env ARMS=c4-160 MODEL=tog-crfs "$(dirname "$0")/run.sh"
