#!/usr/bin/env bash
# RigidFall, session 16 (CPU, 2 cores): the inference module trained on windows that start in
# frames 0-5 (window_span=5, the standard preset's since then) against 0-20, side by side, one
# thread each, then task=evaluate on 100 test videos. Needs a dynamics prior at
# checkpoints/standard/rigid_fall/dynamics/last.ckpt (session 16 used the session-14 GPU prior).
# Rebuilt in session 17 from the README's commands (the original script was ignored and lost).
# Usage: bash scripts/experiments/rigid_fall_window_span.sh [inference minutes, 30]
set -euo pipefail
INF_MIN=${1:-30}
run() { python run.py env=rigid_fall experiment=standard "$@"; }
CK=checkpoints/standard/rigid_fall
run task=generate data.processes=2                          # with video, ~13 min
run task=train_visual                                       # 15 min cap
run task=export_proposals model.inference.window_span=20    # frames for both arms
for span in 5 20; do
  run task=train_inference threads=1 model.inference.window_span=$span model.inference.net.trajectory_start=both \
      trainer.limit_val_batches=50 model.inference.trainer.max_time=00:00:${INF_MIN}:00 paths.ckpt_dir=checkpoints/span$span/rigid_fall \
      ckpt.dynamics=$CK/dynamics/last.ckpt hydra.run.dir=outputs/span$span/train > /tmp/span$span.log 2>&1 &
done
wait
for span in 5 20; do
  run task=evaluate ablation=full eval.max_rollouts=100 eval.curve_rollouts=8 threads=1 paths.ckpt_dir=checkpoints/span$span/rigid_fall \
      ckpt.dynamics=$CK/dynamics/last.ckpt ckpt.visual=$CK/visual/last.ckpt hydra.run.dir=outputs/span$span/evaluate > /tmp/eval_span$span.log 2>&1 &
done
wait
