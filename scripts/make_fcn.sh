#!/usr/bin/env bash
# Reproduce the shipped FCN weights (agents/weights/fcn.pt, docs/vision.md "A model that discriminates"):
# render the data sets, train, evaluate. On 2 CPU cores: aimed views ~12 min (2 rendering processes), rollout
# frames ~15 min, training ~60 min (8 epochs on one thread); see docs/vision.md for the measured times.
# Run from the repository root with the .venv set up.
set -euo pipefail
PY=${PY:-.venv/bin/python}
DATA=${DATA:-data/seg64v2}
ROLLOUT=${ROLLOUT:-data/rollout128}
WORKERS=${WORKERS:-2}
export LP_NUM_THREADS=${LP_NUM_THREADS:-1}  # one render thread per process: the processes share the cores
# Aimed views (segmentation_data.VIEW_MODES: target, distractor, anywhere, lookalike): 30% aimed at a
# distractor of the target's colour or shape, the hard negatives.
PROBS="0.45 0.15 0.1 0.3"
$PY baselines/collect_segmentation_data.py --workers $WORKERS --out-dir $DATA/train       --object-set train  --num-scenes 1500 --seed 0      --view-mode-probs $PROBS
$PY baselines/collect_segmentation_data.py --workers $WORKERS --out-dir $DATA/val         --object-set train  --num-scenes 60   --seed 100000 --view-mode-probs $PROBS
$PY baselines/collect_segmentation_data.py --workers $WORKERS --out-dir $DATA/test_train  --object-set train  --num-scenes 50   --seed 200000
$PY baselines/collect_segmentation_data.py --workers $WORKERS --out-dir $DATA/test_unseen --object-set unseen --num-scenes 50   --seed 300000
# Frames from rollouts on train objects (128², downsampled for training), the servo on the paper model's box
# among them: it walks up to the look-alikes that model mistakes for the target.
$PY baselines/collect_rollout_frames.py --out-dir $ROLLOUT/train --config.object-set train --config.seed 500000 \
  --config.episodes-per-source 50 --config.fcn-weights agents/weights/fcn_paper.pt \
  --config.sources servo_sky explore_servo_sky random_sky random_search servo_fcn_sky
# The held-out test set of rollout frames (unseen objects, seeds 400,000+).
$PY baselines/collect_rollout_frames.py --out-dir $ROLLOUT/test_unseen
$PY baselines/train_fcn.py --data-dir $DATA --extra-train-dirs $ROLLOUT/train --run-dir runs/fcn \
  --epochs 8 --target-pooling masked --shape-kernel 3 --presence-head
cp runs/fcn/best.pt agents/weights/fcn.pt
$PY baselines/eval_fcn.py --weights agents/weights/fcn.pt --largest-component \
  --data-dirs $DATA/test_train $DATA/test_unseen $ROLLOUT/test_unseen
