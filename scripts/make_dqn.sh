#!/usr/bin/env bash
# Reproduce the shipped DQN (agents/weights/dqn.pt): train the chosen preset and seed (default hold_stay_fine, seed
# 0, chosen before training; 100 training episodes, ground-truth box, train objects; one process,
# ~2-3 min on 2 cores), ship it as deployed (FCN box held through its misses, unseen objects, 128²:
# baselines/ship_dqn.py --as-dqn, EnvConfig.as_dqn_deployed: the verifier bars of envs.DQN_FCN_THRESHOLDS, 0.97 to
# acquire a region, 0.9 to keep it; the fine moves of envs.DQN_FINE_STEP_SIZE, half steps near the target, within
# envs.DQN_FINE_NEAR_CENTRE of the image centre and from envs.DQN_FINE_FROM_AREA of the image; a step back when
# pushed too close, envs.DQN_BACK_WHEN_CLOSE; `stay` only where the mask stats say success,
# EnvConfig.stay_needs_success; the held box moving with the camera,
# EnvConfig.box_hold_follows_camera, and dropped once centred and unseen, envs.DQN_BOX_HOLD_DROP_CENTRED; the verifier's
# low bar for regions cut by the border only near the tracked box, EnvConfig.fcn_border_bar_near_box; the exploration
# resuming after an empty box, envs.DQN_EXPLORE_RESUMES_AFTER; the verifier's near-misses approached,
# envs.DQN_FCN_CANDIDATE_THRESHOLD; and the FCN segmenting the camera's frame at its own 128², envs.FCN_SEGMENT_SIZE),
# then evaluate it as deployed on 50 held-out episodes (docs/control.md §9, §11-§12, §17-§21, §25, §27, §30-§32, §34).
# The hold_stay_decay agent shipped before it (trained on the full step, the same fine moves when it acts; no longer
# shipped) is remade by   PRESET=hold_stay_decay SEED=0 OUT=<a file> bash scripts/make_dqn.sh
# The hold_stay agent shipped before it (the shipped memory agent's teacher; docs/search.md) is remade by
#   PRESET=hold_stay SEED=0 OUT=agents/weights/dqn_hold_stay.pt \
#   SHIP_ARGS="--fcn-acquire-threshold 0.97 --fcn-track-threshold 0.9" bash scripts/make_dqn.sh   (no fine moves)
# The six-direction agent shipped before hold_stay (the teacher of an earlier memory agent; docs/search.md) is remade by
#   PRESET=hold_demo_wide SEED=2 OUT=agents/weights/dqn_hold_demo_wide.pt SHIP_ARGS= bash scripts/make_dqn.sh
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
PY=.venv/bin/python
PRESET=${PRESET:-hold_stay_fine}
SEED=${SEED:-0}
OUT=${OUT:-agents/weights/dqn.pt}
RUN=runs/make_dqn/${PRESET}_seed${SEED}
$PY -m mani_active_vision.agents.dqn "$PRESET" --seed "$SEED" --run-dir runs/make_dqn --run-name "${PRESET}_seed${SEED}" "$@"
SHIP_ARGS=${SHIP_ARGS-"--as-dqn"}
# shellcheck disable=SC2086
$PY baselines/ship_dqn.py --checkpoint "$RUN/q_network.pt" --out "$OUT" $SHIP_ARGS
$PY baselines/evaluate.py --policy explore --then dqn --checkpoint "$OUT" --episodes 50 \
    --json "outputs/$(basename "$OUT" .pt)_shipped.json"
