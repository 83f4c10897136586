#!/usr/bin/env bash
# Reproduce the README's five-seed figures for a DQN preset (default the shipped one, hold_stay_fine; docs/control.md
# §12; PRESET=hold_stay_decay for §9's and §11's): train it on seeds 0-4 (100 episodes each, ground-truth box, train
# objects) and evaluate each on 50 held-out episodes (unseen objects) as the shipped DQN is deployed, with the fine
# moves near the target (envs.DQN_FINE_STEP_SIZE): on the ground-truth box (64²), then on the FCN's box (128², the
# box held 20 steps through the FCN's misses, the verifier's bars envs.DQN_FCN_THRESHOLDS, the network segmenting the
# camera's 128², envs.FCN_SEGMENT_SIZE: §17, the fine moves only within envs.DQN_FINE_NEAR_CENTRE of the image
# centre: §18, and from envs.DQN_FINE_FROM_AREA of the image: §32, a step back when pushed too close,
# envs.DQN_BACK_WHEN_CLOSE: §19, `stay` only where the mask stats say success: §21, the held box moving with the
# camera: §25, candidates approached: §34; EnvConfig.as_dqn_deployed), the scripted servo beside
# them. FULL_STEP=1 first evaluates both without the fine moves too (the full step only: §9's figures).
# Two lanes of baselines/seeds.py, one per core with one render thread each (each lane evaluates the servo once
# per box: neither has cached it until it finishes). Finished runs and evaluations under $OUT are skipped on a
# rerun; an evaluation taken with other flags (e.g. before the FCN segmented at 128²) stops it: remove that
# eval_fcn*.json or set OUT. The tables are $OUT/${PRESET}_fine_table.md and $OUT/${PRESET}_fcn_fine_table.md
# (without _fine for FULL_STEP's). About 13 min on 2 cores (about 25 with FULL_STEP=1).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
PY=.venv/bin/python
PRESET=${PRESET:-hold_stay_fine}
OUT=${OUT:-runs/seeds/$PRESET}
# the shipped DQNs' deployment (EnvConfig.as_dqn_deployed): the verifier's bars, the FCN's segmenting size, the fine
# moves' zone and step, the step back when too close, stay only where the mask stats say success, the held box
# moving with the camera and dropped once centred and unseen, the border's low bar only near the tracked box, the
# exploration resuming after an empty box, the verifier's near-misses approached
read -r ACQUIRE TRACK SEGMENT NEAR FROM FINE_STEP BACK DROP RESUME CANDIDATE <<< "$($PY -c "from mani_active_vision import envs as e
print(*e.DQN_FCN_THRESHOLDS, e.FCN_SEGMENT_SIZE, e.DQN_FINE_NEAR_CENTRE, e.DQN_FINE_FROM_AREA, e.DQN_FINE_STEP_SIZE,
      e.DQN_BACK_WHEN_CLOSE, e.DQN_BOX_HOLD_DROP_CENTRED, e.DQN_EXPLORE_RESUMES_AFTER, e.DQN_FCN_CANDIDATE_THRESHOLD)")"
FCN=(--eval-box-source fcn --env.image-size 128 --env.box-hold-steps 20 --env.fcn-acquire-threshold "$ACQUIRE"
    --env.fcn-track-threshold "$TRACK" --env.fcn-segment-size "$SEGMENT" --env.fine-near-centre "$NEAR"
    --env.fine-from-area "$FROM" --env.back-when-close "$BACK" --env.stay-needs-success --env.box-hold-follows-camera
    --env.box-hold-drop-centred "$DROP" --env.fcn-border-bar-near-box --env.explore-resumes-after "$RESUME"
    --env.fcn-candidate-threshold "$CANDIDATE")
lanes() {
    LP_NUM_THREADS=1 $PY baselines/seeds.py --preset "$PRESET" --out-dir "$OUT" --seeds 0 2 4 "$@" >/dev/null &
    local first=$!
    LP_NUM_THREADS=1 $PY baselines/seeds.py --preset "$PRESET" --out-dir "$OUT" --seeds 1 3 "$@" >/dev/null &
    local second=$!
    wait "$first"  # each lane's status: a failed lane stops the script (a bare `wait` would not)
    wait "$second"
    $PY baselines/seeds.py --preset "$PRESET" --out-dir "$OUT" --report-only "$@"
}
FINE=(--eval-fine-step-size "$FINE_STEP")
if [ "${FULL_STEP:-0}" = 1 ]; then
    lanes --eval-fine-step-size 0
    lanes "${FCN[@]}" --eval-fine-step-size 0
fi
lanes "${FINE[@]}"
lanes "${FCN[@]}" "${FINE[@]}"
