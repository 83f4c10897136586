#!/usr/bin/env bash
# Reproduce the shipped FCN weights (agents/weights/fcn.pt): render the data sets, train, evaluate.
# On 2 shared CPU cores: data ~20 min, training ~20-30 min. Run from the repository root with the .venv set up.
set -euo pipefail
PY=${PY:-.venv/bin/python}
DATA=${DATA:-data/seg64}
$PY baselines/collect_segmentation_data.py --out-dir $DATA/train       --object-set train  --num-scenes 300 --seed 0
$PY baselines/collect_segmentation_data.py --out-dir $DATA/val         --object-set train  --num-scenes 50  --seed 100000
$PY baselines/collect_segmentation_data.py --out-dir $DATA/test_train  --object-set train  --num-scenes 50  --seed 200000
$PY baselines/collect_segmentation_data.py --out-dir $DATA/test_unseen --object-set unseen --num-scenes 50  --seed 300000
# 8 epochs, then 8 more resumed under a 16-epoch cosine schedule (a warm restart: how the shipped weights were made)
$PY baselines/train_fcn.py --data-dir $DATA --run-dir runs/fcn --epochs 8
$PY baselines/train_fcn.py --data-dir $DATA --run-dir runs/fcn --epochs 16 --resume
cp runs/fcn/best.pt agents/weights/fcn.pt
$PY baselines/eval_fcn.py --weights agents/weights/fcn.pt --data-dirs $DATA/test_train $DATA/test_unseen
