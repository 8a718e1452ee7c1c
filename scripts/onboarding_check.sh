#!/usr/bin/env bash
# Onboard the objects the tests generate (a mug, a spray bottle, an L-bracket, a tin can, and
# a pitcher, a flared bowl and a spatula from their raw, overlapping parts) into a fresh
# objects folder and check each with a physics campaign in the nominal world, then in the
# realistic one (docs/objects.md, "Measured").
#
#   scripts/onboarding_check.sh [TRIALS] [OUT] [NAME ...]
#
# Defaults: 100 trials per cell, results/onboarding, every generated object (NAME: only those).
#
# OUT/<name>/ gets the onboarding log (choices, stage times), the nominal campaign's
# trials.jsonl, table.md, summary.json and figures, and the installed object folder;
# OUT/<name>/realistic/ the realistic campaign's. The base seed comes from the code version,
# as for rrg-experiment.
set -euo pipefail
cd "$(dirname "$0")/.."
trials=${1:-100}
out=${2:-results/onboarding}
only=" ${*:3} "
chosen() { [ "$only" = "  " ] || [[ "$only" == *" $1 "* ]]; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
export RRG_OBJECTS_DIR="$work/objects"
.venv/bin/python tests/generated_meshes.py "$work/meshes" > "$work/meshes.txt"
while read -r name mesh mass; do
    chosen "$name" || continue
    rm -rf "${out:?}/$name" && mkdir -p "$out/$name"  # nothing of an earlier run stays
    echo "== $name: rrg-object add $mesh --name $name --mass $mass"
    if ! .venv/bin/rrg-object add "$mesh" --name "$name" --mass "$mass" </dev/null \
        2>"$work/add.err" | tee "$out/$name/add.log"; then
        grep -v '%|' "$work/add.err" | tee -a "$out/$name/add.log"  # the refusal, not the bars
        echo "== $name: not installed"
        continue
    fi
    cp -r "$RRG_OBJECTS_DIR/$name" "$out/$name/object"
    echo "== $name: rrg-object check $name --trials $trials"
    .venv/bin/rrg-object check "$name" --trials "$trials" --out "$out/$name" </dev/null
done < "$work/meshes.txt"
while read -r name _ _; do
    chosen "$name" && [ -d "$RRG_OBJECTS_DIR/$name" ] || continue
    echo "== $name: rrg-object check $name --trials $trials --world realistic"
    .venv/bin/rrg-object check "$name" --trials "$trials" --world realistic \
        --out "$out/$name/realistic" </dev/null
done < "$work/meshes.txt"
