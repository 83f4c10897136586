#!/usr/bin/env bash
# Reproduce the shipped memory agent (agents/weights/search.pt) and its measurements (docs/search.md): train
# the memory agent (agents/search.py: DAgger from the scripted exploration handing over to the five-run DQN
# agents/weights/dqn_ensemble.pt (scripts/make_dqn_ensemble.sh), which stays by itself, the exploration's orbit
# first turning back after policies.SWEEP_TURN steps, where one side of the objects' range has been seen; with `stay` and the mask
# stats in its input; with the fine moves near the target as it and its teacher are deployed (envs.DQN_FINE_STEP_SIZE);
# on the FCN's box as deployed: 128², held through its misses, the verifier's bars envs.DQN_FCN_THRESHOLDS;
# a focal imitation loss and a policy head that sees the current step's input beside the GRU's;
# train objects, 2 worker processes, 20,000 env steps, ~7 min) for each seed, evaluate every seed and the
# baselines on 50 held-out episodes (unseen objects, FCN box as deployed and ground-truth box), draw the learning
# curves and the camera's azimuth, then ship seed 0 (chosen before training, not the best) as deployed (FCN box,
# unseen objects, `stay` only where the mask stats say success: baselines/ship_dqn.py) and evaluate it. The seeds
# are evaluated as deployed too (search_seeds.py --stay-needs-success: their own evaluation files). Finished runs
# and evaluations are kept under $OUT (runs/search_turn) and skipped on a rerun. About 60 min on 2 cores.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
PY=.venv/bin/python
SEEDS=${SEEDS:-0 1 2 3 4}
STEPS=${STEPS:-20000}
SHIP_SEED=${SHIP_SEED:-0}
OUT=${OUT:-runs/search_turn}
# the FCN's box as the shipped DQN is deployed (EnvConfig.on_fcn_box(DQN_FCN_THRESHOLDS)): size, held steps, bars
read -r SIZE HOLD ACQUIRE TRACK FINE TURN < <($PY -c "from mani_active_vision import envs
from mani_active_vision.agents import policies
print(envs.FCN_IMAGE_SIZE, envs.FCN_BOX_HOLD_STEPS, *envs.DQN_FCN_THRESHOLDS, envs.DQN_FINE_STEP_SIZE, policies.SWEEP_TURN)")
TEACHER=(--train.teacher agents/weights/dqn_ensemble.pt --dqn-checkpoint agents/weights/dqn_ensemble.pt --train.env.stay-action
    --train.env.with-mask-stats --train.env.fine-step-size "$FINE" --train.dagger-updates 32 --train.dagger-focal-gamma 2
    --train.actor-sees-input --train.teacher-first-turn "$TURN")
ON_FCN_BOX=(--train.env.box-source fcn --train.env.image-size "$SIZE" --train.env.box-hold-steps "$HOLD"
    --train.env.fcn-acquire-threshold "$ACQUIRE" --train.env.fcn-track-threshold "$TRACK" --fcn-thresholds "$ACQUIRE" "$TRACK")
# shellcheck disable=SC2086
$PY baselines/search_seeds.py --seeds $SEEDS --total-steps "$STEPS" "${TEACHER[@]}" "${ON_FCN_BOX[@]}" --out-dir "$OUT" \
    --stay-needs-success "$@"
$PY baselines/ship_dqn.py --checkpoint "$OUT/seed$SHIP_SEED/agent.pt" --out agents/weights/search.pt \
    --fcn-acquire-threshold "$ACQUIRE" --fcn-track-threshold "$TRACK" --stay-needs-success
$PY baselines/evaluate.py --policy memory --checkpoint agents/weights/search.pt --episodes 50 \
    --json outputs/search_shipped.json
