#!/bin/bash
# The five shipped networks: same size (width 0.25, ResNet-18 or VGG-16 backbone), same data, same schedule
# (2000 SGD steps of 8 images at 160x120 = 8 epochs of the 2040 training frames, lr 0.05, poly 0.9, seed 0),
# one CPU thread each, run one after another.  Data: python scripts/make_training_data.py --out outputs/train-data
# Afterwards: python scripts/ship_weights.py copies each run's best.pt into weights/ and writes the manifest.
#
# Pretrained starts (issue 32): INIT=espnetv2-pascal-s1 SIZE=320x240 LR=0.02 DATA=outputs/train-data-320
# RUNS=outputs/runs-320 puts every head on the ESPNetv2 PASCAL encoder (data: make_training_data.py --image-size
# 320x240); the same command runs on a GPU with DEVICE=cuda.  An interrupted run continues with --resume.
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${DATA:-outputs/train-data}
RUNS=${RUNS:-outputs/train-runs}
MODELS=${MODELS:-"cbam-pspnet pspnet fcn rgb-only rgbd-net"}
SIZE=${SIZE:-160x120}
LR=${LR:-0.05}
ITERATIONS=${ITERATIONS:-2000}
DEVICE=${DEVICE:-cpu}
THREADS=${THREADS:-1}
INIT=${INIT:-}
mkdir -p "$RUNS"
for model in $MODELS; do
  if [ -f "$RUNS/$model/final.pt" ]; then continue; fi
  extra=""
  if [ -f "$RUNS/$model/last.pt" ]; then extra="--resume"; fi
  if [ -n "$INIT" ]; then extra="$extra --init $INIT"; fi
  nice -n 15 semmap train --model "$model" --data "$DATA/train" --val "$DATA/val" --out "$RUNS/$model" \
    --iterations "$ITERATIONS" --batch 8 --lr "$LR" --input-size "$SIZE" --width 0.25 --resnet-depth 18 --seed 0 \
    --threads "$THREADS" --device "$DEVICE" --eval-every 100 $extra > "$RUNS/$model.log" 2>&1
done
