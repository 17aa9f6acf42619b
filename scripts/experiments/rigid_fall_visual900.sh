#!/usr/bin/env bash
# Session 19 (CPU, 2 cores), issue 4. Two questions:
#  1. RigidFall: the standard visual prior holds 200 of the 900 training videos in memory
#     (model.visual.max_rollouts: 200) and overfits (session 18: training position loss 0.068
#     against 0.240 on validation). Trained on all 900 (uint8 video, ~6.2 GB) at the same 15-min
#     cap, is its test error lower, and is gravity from video better with its proposals? Session
#     18's row to compare with, with the same prior recipe (seed 1, 45 min) and inference arm
#     (lr 1e-4, one thread, 30 min): visual test MSE x 1e4 33.8, gravity 19.2% (11.7), T+20 165.3.
#  2. MassRope: session 14's 1-thread fp32 priors rolled out well (T+20 8.5-20 against session 7's
#     169) but were never put through the identifiability oracle. Does a prior of that recipe pin
#     stiffness down (oracle below the midpoint's MAE)? Session 7's prior preferred the stiffest rope
#     (oracle 35.9% against 29.1%). Trained on the second core beside the RigidFall inference arm.
# Usage: bash scripts/experiments/rigid_fall_visual900.sh [prior seed, 1] [prior minutes, 45] [inference minutes, 30]
set -euo pipefail
SEED=${1:-1}; PRIOR_MIN=${2:-45}; INF_MIN=${3:-30}
run() { python run.py env=rigid_fall experiment=standard "$@"; }
CK=checkpoints/standard/rigid_fall
run task=generate data.processes=2                                              # with video, 2.6 min (AMD EPYC)
run task=train_visual '+model.visual.trainer.precision=${fast_precision:bf16-mixed}' model.visual.max_rollouts=null \
    hydra.run.dir=outputs/visual900                                             # 15 min cap, all 900 videos
run task=export_proposals hydra.run.dir=outputs/export900
run task=train_dynamics seed=$SEED ckpt_path=last trainer.max_time=00:00:${PRIOR_MIN}:00 hydra.run.dir=outputs/prior_seed$SEED
# second core: the MassRope prior (data without video), then its oracle sweep
( python run.py task=generate env=mass_rope experiment=standard data.render=false data.processes=1 hydra.run.dir=outputs/mr_generate
  python run.py task=train_dynamics env=mass_rope experiment=standard seed=1 threads=1 trainer.precision=32-true \
      trainer.max_time=00:00:$((INF_MIN + 5)):00 hydra.run.dir=outputs/mr_prior
  python run.py task=evaluate_dynamics env=mass_rope experiment=standard threads=1 eval.max_rollouts=40 task.param_grid=9 \
      ckpt_path=checkpoints/standard/mass_rope/dynamics/last.ckpt hydra.run.dir=outputs/mr_oracle ) > /tmp/mass_rope.log 2>&1 &
run task=train_inference threads=1 model.inference.net.trajectory_start=both trainer.limit_val_batches=50 \
    model.inference.trainer.max_time=00:00:${INF_MIN}:00 ckpt.dynamics=$CK/dynamics/last.ckpt \
    paths.ckpt_dir=checkpoints/visual900/rigid_fall hydra.run.dir=outputs/visual900_inference > /tmp/visual900_inference.log 2>&1
run task=evaluate ablation=full eval.max_rollouts=100 eval.curve_rollouts=8 threads=1 paths.ckpt_dir=checkpoints/visual900/rigid_fall \
    ckpt.dynamics=$CK/dynamics/last.ckpt ckpt.visual=$CK/visual/last.ckpt hydra.run.dir=outputs/visual900_evaluate > /tmp/eval_visual900.log 2>&1
wait
grep -h '"param_mae_pct\|future_mse_x1e4@20\|refine_mse' outputs/visual900_evaluate/metrics.json
grep -h 'oracle' outputs/mr_oracle/metrics.json
# then (session 19, beside the test suite): the inference module resumed to the 55-min cap (max_epochs=3 stops it at 1,800 steps: the resume starts a new epoch)
run task=train_inference threads=1 model.inference.net.trajectory_start=both trainer.limit_val_batches=50 \
    model.inference.trainer.max_time=00:00:55:00 ckpt.dynamics=$CK/dynamics/last.ckpt ckpt_path=last \
    paths.ckpt_dir=checkpoints/visual900/rigid_fall hydra.run.dir=outputs/visual900_inference_55
run task=evaluate ablation=full eval.max_rollouts=100 eval.curve_rollouts=8 paths.ckpt_dir=checkpoints/visual900/rigid_fall \
    ckpt.dynamics=$CK/dynamics/last.ckpt ckpt.visual=$CK/visual/last.ckpt hydra.run.dir=outputs/visual900_evaluate_1800
