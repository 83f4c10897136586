#!/usr/bin/env bash
# Reproduce the shipped FCN weights (agents/weights/fcn.pt): the segmentation network and its verifier.
# 1. render the aimed-view data sets; 2. train the segmentation network (the paper's design); 3. roll the
# project's policies out on train objects for frames of what they see; 4. train the verifier of the
# network's candidate regions on those frames; 5. evaluate on the test sets and on held-out rollout frames.
# On 2 CPU cores (one thread per process): see docs/vision.md for the last end-to-end run's times.
# Run from the repository root with the .venv set up.
set -euo pipefail
PY=${PY:-.venv/bin/python}
DATA=${DATA:-data/seg64}
ROLLOUT=${ROLLOUT:-data/rollout128}
WORKERS=${WORKERS:-2}
export LP_NUM_THREADS=1
$PY baselines/collect_segmentation_data.py --workers $WORKERS --out-dir $DATA/train       --object-set train  --num-scenes 1500 --seed 0
$PY baselines/collect_segmentation_data.py --workers $WORKERS --out-dir $DATA/val         --object-set train  --num-scenes 50   --seed 100000
$PY baselines/collect_segmentation_data.py --workers $WORKERS --out-dir $DATA/test_train  --object-set train  --num-scenes 50   --seed 200000
$PY baselines/collect_segmentation_data.py --workers $WORKERS --out-dir $DATA/test_unseen --object-set unseen --num-scenes 50   --seed 300000
# the defaults of train_fcn.py are the segmentation network's recipe: 12 epochs, flips, cross-entropy + soft IoU
$PY baselines/train_fcn.py --data-dir $DATA --run-dir runs/fcn
# frames from rollouts on train objects (the servo on this network's box walks up to its look-alikes);
# four collections, two at a time side by side, one per core
SOURCES="servo_sky explore_servo_sky random_sky random_search servo_fcn_sky"
collect() {
  $PY baselines/collect_rollout_frames.py --out-dir $ROLLOUT/train_$1 --config.object-set train --config.seed $2 \
    --config.episodes-per-source 75 --config.sources $SOURCES --config.fcn-weights runs/fcn/best.pt
}
collect a 500000 & FIRST=$!; collect b 600000 & wait $FIRST; wait $!
collect c 700000 & FIRST=$!; collect d 800000 & wait $FIRST; wait $!
# the verifier: pairs also turned together (up to 45°), saved with the bar control needs (0.9) and a bar of 0.3
# for regions cut by the image's border that cover at least 2.5% of it
$PY baselines/train_verifier.py --fcn runs/fcn/best.pt --data-dirs $ROLLOUT/train_a $ROLLOUT/train_b \
  $ROLLOUT/train_c $ROLLOUT/train_d --rotate 45 --threshold 0.9 --cut-share 0.025 --cut-threshold 0.3 --run-dir runs/verifier
cp runs/verifier/best.pt agents/weights/fcn.pt
[ -f $ROLLOUT/test_unseen/manifest.json ] || $PY baselines/collect_rollout_frames.py --out-dir $ROLLOUT/test_unseen
$PY baselines/eval_fcn.py --weights agents/weights/fcn.pt --data-dirs $DATA/test_train $DATA/test_unseen --largest-component
$PY baselines/eval_fcn.py --weights agents/weights/fcn.pt --data-dirs $ROLLOUT/test_unseen --largest-component \
  --out outputs/fcn_eval_rollout.md --examples-png outputs/fcn_examples_rollout.png
# the frames the shipped DQN sees as deployed (on this FCN's box, segmenting at 128²): rendered again for each FCN
$PY baselines/collect_rollout_frames.py --out-dir $ROLLOUT/test_unseen_dqn --config.episodes-per-source 50 \
  --config.sources dqn_fcn_sky
$PY baselines/eval_fcn.py --weights agents/weights/fcn.pt --data-dirs $ROLLOUT/test_unseen_dqn --largest-component \
  --segment-size 128 --out outputs/fcn_eval_dqn_frames.md --examples-png outputs/fcn_examples_dqn_frames.png
