#!/usr/bin/env bash
# Reproduce the README's five-seed figures for a DQN preset (default the shipped one, hold_stay_decay;
# docs/control.md §9; PRESET=hold_stay for §7's): train it on seeds 0-4 (100 episodes each, ground-truth box,
# train objects) and evaluate each on 50 held-out episodes (unseen objects) on the ground-truth box (64²), then on
# the FCN's box as the shipped DQN is deployed (128², the box held 20 steps through the FCN's misses, the
# verifier's bars envs.DQN_FCN_THRESHOLDS), the scripted servo beside them; then both again with the fine moves near
# the target (envs.DQN_FINE_STEP_SIZE), as the shipped DQN is deployed (docs/control.md §11).
# Two lanes of baselines/seeds.py, one per core with one render thread each (each lane evaluates the servo once
# per box: neither has cached it until it finishes). Finished runs and evaluations under $OUT are skipped on a
# rerun; the tables are $OUT/$PRESET_table.md, $OUT/$PRESET_fcn_table.md and the same with _fine. About 45 min on
# 2 cores.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
PY=.venv/bin/python
PRESET=${PRESET:-hold_stay_decay}
OUT=${OUT:-runs/seeds/$PRESET}
BARS=$($PY -c "from mani_active_vision.envs import DQN_FCN_THRESHOLDS as t; print(*t)")  # acquire, track
FCN=(--eval-box-source fcn --env.image-size 128 --env.box-hold-steps 20
    --env.fcn-acquire-threshold "${BARS% *}" --env.fcn-track-threshold "${BARS#* }")
lanes() {
    LP_NUM_THREADS=1 $PY baselines/seeds.py --preset "$PRESET" --out-dir "$OUT" --seeds 0 2 4 "$@" >/dev/null &
    LP_NUM_THREADS=1 $PY baselines/seeds.py --preset "$PRESET" --out-dir "$OUT" --seeds 1 3 "$@" >/dev/null &
    wait
    $PY baselines/seeds.py --preset "$PRESET" --out-dir "$OUT" --report-only "$@"
}
FINE=(--eval-fine-step-size "$($PY -c "from mani_active_vision.envs import DQN_FINE_STEP_SIZE as f; print(f)")")
lanes
lanes "${FCN[@]}"
lanes "${FINE[@]}"
lanes "${FCN[@]}" "${FINE[@]}"
