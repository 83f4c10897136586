#!/usr/bin/env bash
# Reproduce agents/weights/dqn_ensemble.pt (docs/control.md §14): five runs of the shipped DQN's preset
# (hold_stay_fine, seeds 0-4, 100 training episodes each; seed 0's run is agents/weights/dqn.pt's) shipped as one
# agent acting on the mean of their Q-values, deployed as dqn.pt is (the FCN's box on unseen objects, its bars and
# segmenting size, the fine moves and their zone), then evaluated on 50 held-out episodes. It has learned from 500 episodes, five times the
# shipped agent's budget. ~6-8 min on 2 cores (two runs at a time).
#   bash scripts/make_dqn_ensemble.sh                     # -> agents/weights/dqn_ensemble.pt
#   SEEDS="5 6 7 8 9" OUT=/tmp/ensemble.pt bash scripts/make_dqn_ensemble.sh   # another five runs
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
PY=.venv/bin/python
PRESET=${PRESET:-hold_stay_fine}
read -r -a SEEDS <<< "${SEEDS:-0 1 2 3 4}"
OUT=${OUT:-agents/weights/dqn_ensemble.pt}
run() { echo "runs/make_dqn/${PRESET}_seed$1"; }
train() {  # the runs of make_dqn.sh, one after another
    for seed in "$@"; do
        LP_NUM_THREADS=1 $PY -m mani_active_vision.agents.dqn "$PRESET" --seed "$seed" --run-dir runs/make_dqn \
            --run-name "${PRESET}_seed$seed" > "$(run "$seed").log" 2>&1
    done
}
mkdir -p runs/make_dqn
train "${SEEDS[@]::(${#SEEDS[@]} + 1) / 2}" &
FIRST=$!
train "${SEEDS[@]:(${#SEEDS[@]} + 1) / 2}" &
SECOND=$!
wait "$FIRST"  # each lane's status: one that fails stops the script before it ships (a bare `wait` would not)
wait "$SECOND"
MEMBERS=()
for seed in "${SEEDS[@]:1}"; do MEMBERS+=("$(run "$seed")/q_network.pt"); done
$PY baselines/ship_dqn.py --checkpoint "$(run "${SEEDS[0]}")/q_network.pt" --members "${MEMBERS[@]}" --out "$OUT" \
    --as-dqn  # deployed as dqn.pt is: EnvConfig.as_dqn_deployed
$PY baselines/evaluate.py --policy explore --then dqn --checkpoint "$OUT" --episodes 50 \
    --json "outputs/$(basename "$OUT" .pt)_shipped.json"
