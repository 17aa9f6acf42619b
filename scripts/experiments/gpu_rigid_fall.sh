#!/usr/bin/env bash
# RigidFall, the standard preset's stages on one GPU with 16 CPU cores (the lent H100 of sessions
# 14-15), each stage time-capped so that the whole run fits a 30-minute device lease.
# Session 15 ran these stages (its script was ignored and lost with its checkout; this is rebuilt
# from the README's commands in session 17). The two inference arms test session 17's finding on
# the CPU with perfect proposals, now with the visual prior's: inference lr 1e-4 (the preset) against
# 1e-3, both on the preset's windows (frames 0-5). Run it detached and poll the log: one device
# call may last 10 minutes.
# Usage: bash scripts/experiments/gpu_rigid_fall.sh [seed, 0] [prior minutes, 12] [inference minutes, 6]
set -euo pipefail
SEED=${1:-0}; PRIOR_MIN=${2:-12}; INF_MIN=${3:-6}
run() { python run.py env=rigid_fall experiment=standard seed=$SEED "$@"; }
CK=checkpoints/standard/rigid_fall
run task=generate data.processes=16                                    # 1000 rendered rollouts, ~1 min
run task=train_dynamics ckpt_path=last threads=8 trainer.max_time=00:00:${PRIOR_MIN}:00
run task=train_visual threads=8 model.visual.trainer.max_time=00:00:03:00
run task=export_proposals model.inference.max_rollouts=600   # export runs on the CPU cores
common=(task=train_inference threads=4 model.inference.max_rollouts=600 model.inference.batch_size=8
        model.inference.net.trajectory_start=both model.inference.trainer.max_time=00:00:${INF_MIN}:00 ckpt.dynamics=$CK/dynamics/last.ckpt)
for lr in 1e-4 1e-3; do
  run "${common[@]}" model.inference.net.lr=$lr paths.ckpt_dir=checkpoints/lr$lr/rigid_fall \
      hydra.run.dir=outputs/lr$lr/train > logs_lr$lr.txt 2>&1 &
done
wait
for lr in 1e-4 1e-3; do
  run task=evaluate ablation=full eval.max_rollouts=100 eval.curve_rollouts=8 threads=4 paths.ckpt_dir=checkpoints/lr$lr/rigid_fall \
      ckpt.dynamics=$CK/dynamics/last.ckpt ckpt.visual=$CK/visual/last.ckpt hydra.run.dir=outputs/lr$lr/evaluate > logs_eval$lr.txt 2>&1 &
done
wait
grep -h "param_mae_pct\|future_mse" outputs/lr*/evaluate/metrics.json
