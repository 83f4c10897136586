#!/usr/bin/env bash
# Reproduce the shipped memory agent (agents/weights/search.pt) and its measurements (docs/search.md): train
# the memory agent (agents/search.py, recurrent PPO, ground-truth box, train objects, 2 worker processes) for
# each seed, evaluate every seed and the baselines on 50 held-out episodes (unseen objects, FCN box and
# ground-truth box), draw the learning curves and the camera's azimuth, then ship seed 0 (chosen before
# training, not the best) as deployed (FCN box, unseen objects: baselines/ship_dqn.py) and evaluate it.
# Finished runs and evaluations are kept under runs/search_seeds and skipped on a rerun.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
PY=.venv/bin/python
SEEDS=${SEEDS:-0 1 2}
STEPS=${STEPS:-50000}
SHIP_SEED=${SHIP_SEED:-0}
# shellcheck disable=SC2086
$PY baselines/search_seeds.py --seeds $SEEDS --total-steps "$STEPS" "$@"
# the memory agent was measured on the FCN's box as it is, not held through its misses
$PY baselines/ship_dqn.py --checkpoint "runs/search_seeds/seed$SHIP_SEED/agent.pt" --out agents/weights/search.pt \
  --box-hold-steps 0
$PY baselines/evaluate.py --policy memory --checkpoint agents/weights/search.pt --episodes 50 \
    --json outputs/search_shipped.json
