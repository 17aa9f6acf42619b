#!/usr/bin/env bash
# Session 21 (CPU, 2 cores, AMD EPYC), issue 4, RigidFall. Session 19's inference module read gravity
# from video at 10.9% after 1,170 steps and 13.0% after 1,800: the slope of inferred against true
# gravity held, the global offset wandered. Does an exponential moving average of its weights
# (model.inference.ema.decay: at 0.998, the mean of every step until it spans 500, then an EMA over ~500) settle it? One run gives both arms: last.ckpt's
# state_dict is the average, its current_model_state the weights being trained (trained.ckpt below).
# Needs session 19's checkpoints and data: the seed-1 standard prior, the 900-video visual prior and
# its exported proposals (scripts/experiments/rigid_fall_visual900.sh).
# Usage: bash scripts/experiments/rigid_fall_ema.sh [decay, 0.998] [steps, 1800]
set -euo pipefail
DECAY=${1:-0.998}; STEPS=${2:-1800}
run() { python run.py env=rigid_fall experiment=standard "$@"; }
CK=checkpoints/standard/rigid_fall
OUT=checkpoints/ema/rigid_fall
run task=train_inference threads=1 model.inference.net.trajectory_start=both trainer.limit_val_batches=50 \
    model.inference.ema.decay=$DECAY model.inference.trainer.max_steps=$STEPS model.inference.trainer.max_time=00:01:15:00 \
    ckpt.dynamics=$CK/dynamics/last.ckpt paths.ckpt_dir=$OUT hydra.run.dir=outputs/ema_inference     # 47 min at 0.64 steps/s
python -c "from vgpl.weight_averaging import trained_weights_checkpoint as t; t('$OUT/inference/last.ckpt', '$OUT/inference/trained.ckpt')"
# both arms on the same 100 test videos, side by side, one thread each
for arm in last trained; do
  run task=evaluate ablation=full eval.max_rollouts=100 eval.curve_rollouts=8 threads=1 paths.ckpt_dir=$OUT \
      ckpt.dynamics=$CK/dynamics/last.ckpt ckpt.visual=$CK/visual/last.ckpt ckpt.inference=$OUT/inference/$arm.ckpt \
      hydra.run.dir=outputs/ema_evaluate_$arm > /tmp/ema_evaluate_$arm.log 2>&1 &
done
wait
grep -h '"param_mae_pct\|future_mse_x1e4@20\|refine_mse' outputs/ema_evaluate_*/metrics.json
