#!/bin/bash
# The five shipped networks: same size (width 0.25, ResNet-18 or VGG-16 backbone), same data, same schedule
# (2000 SGD steps of 8 images at 160x120 = 8 epochs of the 2040 training frames, lr 0.05, poly 0.9, seed 0),
# one CPU thread each, run one after another.  Data: python scripts/make_training_data.py --out outputs/train-data
# Afterwards: python scripts/ship_weights.py copies each run's best.pt into weights/ and writes the manifest.
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${DATA:-outputs/train-data}
RUNS=${RUNS:-outputs/train-runs}
MODELS=${MODELS:-"cbam-pspnet pspnet fcn rgb-only rgbd-net"}
for model in $MODELS; do
  if [ -f "$RUNS/$model/final.pt" ]; then continue; fi
  resume=""
  if [ -f "$RUNS/$model/last.pt" ]; then resume="--resume"; fi
  nice -n 15 semmap train --model "$model" --data "$DATA/train" --val "$DATA/val" --out "$RUNS/$model" \
    --iterations 2000 --batch 8 --lr 0.05 --input-size 160x120 --width 0.25 --resnet-depth 18 --seed 0 \
    --threads 1 --eval-every 100 $resume > "$RUNS/$model.log" 2>&1
done
