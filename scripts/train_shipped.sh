#!/bin/bash
# The five shipped networks (issue 32): each head of the papers on the ESPNetv2 s=1.0 encoder pretrained on ImageNet
# and PASCAL VOC (--init espnetv2-pascal-s1, ../shared/weights/espnetv2), same data and schedule: 1000 SGD steps of
# 8 images at 320x240 (4 epochs of the 2040 training frames), lr 0.02, poly 0.9, seed 0, one CPU thread each
# (about 1.5 CPU-s a step; the five ran two or three at a time on two shared cores, 30-35 min each).
# Data: python scripts/make_training_data.py --out outputs/train-data-320 --image-size 320x240
# The shipped fcn had more: 360 scenes (make_training_data.py ... --extra 240, DATA's train-extra/ added as a second
# --data) and 2000 steps on two threads; its exact command is in weights/manifest.json.
# Afterwards: python scripts/calibrate_weights.py --weights RUNS/NET/best.pt --scenes 8 --out CAL/NET.pt for each
# network (the temperature fitted on full-size validation frames), then python scripts/ship_weights.py --runs
# outputs/runs-320 --bench BENCH.json --calibrated CAL copies them into weights/ and writes the manifest.  The same command runs on a GPU with DEVICE=cuda; an interrupted run
# continues with --resume.  The earlier scratch networks: INIT= SIZE=160x120 LR=0.05 ITERATIONS=2000
# DATA=outputs/train-data RUNS=outputs/train-runs (data: make_training_data.py --image-size 160x120).
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${DATA:-outputs/train-data-320}
RUNS=${RUNS:-outputs/runs-320}
MODELS=${MODELS:-"cbam-pspnet pspnet fcn rgb-only rgbd-net"}
SIZE=${SIZE:-320x240}
LR=${LR:-0.02}
ITERATIONS=${ITERATIONS:-1000}
DEVICE=${DEVICE:-cpu}
THREADS=${THREADS:-1}
INIT=${INIT-espnetv2-pascal-s1}
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
