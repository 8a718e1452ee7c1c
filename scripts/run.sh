#!/usr/bin/env bash
# The main job: set everything up, launch the simulated ROS 2 graph (MuJoCo WAM + BarrettHand,
# executor, estimator, planner, bag recorder), run one robust grasp of the power drill at
# high uncertainty (σ = 5 cm, 5 cm, 30°) with RRG-Info, print the outcome, and leave the bag in
# bags/. Extra arguments go to rrg-launch, e.g. scripts/run.sh --grasp box --level low
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$ROOT/scripts/setup.sh"
cd "$ROOT"
exec "$ROOT/.venv/bin/rrg-launch" --mode sim --grasp powerdrill --level high --strategy rrg-info "$@"
