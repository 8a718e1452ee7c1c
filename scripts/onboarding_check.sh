#!/usr/bin/env bash
# Onboard the three objects the tests generate (a mug, a spray bottle, an L-bracket) into a
# fresh objects folder and check each with a physics campaign (docs/objects.md, "Measured").
#
#   scripts/onboarding_check.sh [TRIALS] [OUT]     # defaults: 100 trials per cell, results/onboarding
#
# OUT/<name>/ gets the onboarding log (choices, stage times), the campaign's trials.jsonl,
# table.md, summary.json and figures, and the installed object folder. The base seed comes
# from the code version, as for rrg-experiment.
set -euo pipefail
cd "$(dirname "$0")/.."
trials=${1:-100}
out=${2:-results/onboarding}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
export RRG_OBJECTS_DIR="$work/objects"
.venv/bin/python tests/generated_meshes.py "$work/meshes" | while read -r name mesh mass; do
    mkdir -p "$out/$name"
    echo "== $name: rrg-object add $mesh --name $name --mass $mass"
    .venv/bin/rrg-object add "$mesh" --name "$name" --mass "$mass" </dev/null 2>/dev/null | tee "$out/$name/add.log"
    rm -rf "$out/$name/object"
    cp -r "$RRG_OBJECTS_DIR/$name" "$out/$name/object"
    echo "== $name: rrg-object check $name --trials $trials"
    .venv/bin/rrg-object check "$name" --trials "$trials" --out "$out/$name" </dev/null
done
