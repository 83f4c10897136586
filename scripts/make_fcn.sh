#!/usr/bin/env bash
# Reproduce the shipped FCN weights (agents/weights/fcn.pt): render the data sets, train, evaluate.
# On 2 CPU cores: data ~10 min (2 rendering processes), training ~50 min (12 epochs on one thread).
# Run from the repository root with the .venv set up.
set -euo pipefail
PY=${PY:-.venv/bin/python}
DATA=${DATA:-data/seg64}
WORKERS=${WORKERS:-2}
$PY baselines/collect_segmentation_data.py --workers $WORKERS --out-dir $DATA/train       --object-set train  --num-scenes 1500 --seed 0
$PY baselines/collect_segmentation_data.py --workers $WORKERS --out-dir $DATA/val         --object-set train  --num-scenes 50   --seed 100000
$PY baselines/collect_segmentation_data.py --workers $WORKERS --out-dir $DATA/test_train  --object-set train  --num-scenes 50   --seed 200000
$PY baselines/collect_segmentation_data.py --workers $WORKERS --out-dir $DATA/test_unseen --object-set unseen --num-scenes 50   --seed 300000
# the defaults of train_fcn.py are the shipped recipe: 12 epochs, flips, cross-entropy + soft IoU, full-resolution skip
$PY baselines/train_fcn.py --data-dir $DATA --run-dir runs/fcn
cp runs/fcn/best.pt agents/weights/fcn.pt
$PY baselines/eval_fcn.py --weights agents/weights/fcn.pt --data-dirs $DATA/test_train $DATA/test_unseen --largest-component
