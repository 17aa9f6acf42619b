#!/usr/bin/env bash
# Session 23 (CPU, 2 cores, AMD EPYC), issue 4, FluidCube: does viscosity get learnt through the
# 40.2k-step prior (oracle 14.8% at horizon 5) with more steps? Needs session 22's checkpoints and
# data (scripts/experiments/fluid_cube_rerun.sh). Two arms side by side, one thread each:
#   A: session 22's run (one shared encoder, 823 steps) resumed; the timer carries over, so its
#      max_time counts session 22's 20 minutes.
#   B: the paper's two encoders (separate_param_net=true) from scratch, with the weight EMA
#      (last.ckpt holds the averaged weights, trained.ckpt the trained ones).
# Then task=evaluate on 100 test videos for A, B (EMA) and B (trained weights), one thread each.
# As run. Usage: bash scripts/experiments/fluid_cube_inference_long.sh [minutes, 115]
set -euo pipefail
MIN=${1:-115}
run() { python run.py env=fluid_cube experiment=standard "$@"; }
CK=checkpoints/standard/fluid_cube
SEP=checkpoints/sep/fluid_cube
hm() { printf '%02d:%02d:00' $(($1 / 60)) $(($1 % 60)); }
common=(task=train_inference threads=1 model.inference.net.trajectory_start=both trainer.limit_val_batches=50
        model.inference.trainer.max_steps=20000)
run "${common[@]}" ckpt_path=last model.inference.trainer.max_time=00:$(hm $((MIN + 20))) \
    hydra.run.dir=outputs/fc_inference_resumed > /tmp/s23/armA.log 2>&1 &
run "${common[@]}" model.inference.net.separate_param_net=true model.inference.ema.decay=0.998 \
    model.inference.trainer.max_time=00:$(hm "$MIN") ckpt.dynamics=$CK/dynamics/last.ckpt paths.ckpt_dir=$SEP \
    hydra.run.dir=outputs/fc_inference_sep > /tmp/s23/armB.log 2>&1 &
wait
python -c "from vgpl.weight_averaging import trained_weights_checkpoint as t; t('$SEP/inference/last.ckpt', '$SEP/inference/trained.ckpt')"
evaluate=(task=evaluate ablation=full threads=1 eval.max_rollouts=100 eval.curve_rollouts=8
          ckpt.dynamics=$CK/dynamics/last.ckpt ckpt.visual=$CK/visual/last.ckpt)
run "${evaluate[@]}" hydra.run.dir=outputs/fc_evaluate_resumed &
run "${evaluate[@]}" paths.ckpt_dir=$SEP ckpt.inference=$SEP/inference/last.ckpt hydra.run.dir=outputs/fc_evaluate_sep_ema &
wait
run "${evaluate[@]}" paths.ckpt_dir=$SEP ckpt.inference=$SEP/inference/trained.ckpt hydra.run.dir=outputs/fc_evaluate_sep_trained
grep -h '"param_mae_pct\|future_mse_x1e4@20\|refine_mse' outputs/fc_evaluate_{resumed,sep_ema,sep_trained}/metrics.json
