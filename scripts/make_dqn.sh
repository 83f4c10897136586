#!/usr/bin/env bash
# Reproduce the shipped DQN (agents/weights/dqn.pt): train the chosen preset and seed (default hold_demo_wide,
# seed 2: the best of five on the FCN's box; 100 training episodes, ground-truth box, train objects; one process,
# ~2-3 min on 2 cores), ship it as deployed (FCN box held through its misses, unseen objects, 128²:
# baselines/ship_dqn.py), then evaluate it as deployed on 50 held-out episodes (docs/control.md §6).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
PY=.venv/bin/python
PRESET=${PRESET:-hold_demo_wide}
SEED=${SEED:-2}
$PY -m mani_active_vision.agents.dqn "$PRESET" --seed "$SEED" --run-dir runs/make_dqn --run-name shipped "$@"
$PY baselines/ship_dqn.py --checkpoint runs/make_dqn/shipped/q_network.pt --out agents/weights/dqn.pt
$PY baselines/evaluate.py --policy explore --then dqn --checkpoint agents/weights/dqn.pt --episodes 50 \
    --json outputs/dqn_shipped.json
