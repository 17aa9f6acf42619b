#!/usr/bin/env bash
# Session 24 (CPU, 2 cores, AMD EPYC), issue 4. On FluidCube (session 23) viscosity followed the scene
# only with the paper's separate parameter encoder (r 0.75 against 0.05 with the shared one). MassRope's
# stiffness and RigidFall's gravity had been read by the shared encoder (session 21: MassRope r 0.12,
# a constant; RigidFall r 0.92, offset and shrunk). Does the separate encoder help them too?
# One inference module per env, side by side on one thread each, EMA on (one run gives both arms);
# the priors, visual priors and proposals of sessions 19-21 (rigid_fall_visual900.sh, mass_rope_bounce.sh).
# Usage: bash scripts/experiments/separate_param_net.sh [max_time, 00:01:35:00]
set -euo pipefail
TIME=${1:-00:01:35:00}
for env in mass_rope rigid_fall; do
  python run.py env=$env experiment=standard task=train_inference threads=1 \
    model.inference.net.trajectory_start=both model.inference.net.separate_param_net=true \
    model.inference.ema.decay=0.998 trainer.limit_val_batches=50 \
    model.inference.trainer.max_steps=20000 model.inference.trainer.max_time=$TIME \
    ckpt.dynamics=checkpoints/standard/$env/dynamics/last.ckpt paths.ckpt_dir=checkpoints/sep/$env \
    hydra.run.dir=outputs/sep_inference_$env > /tmp/sep_inference_$env.log 2>&1 &
done
wait
# (in session 24 a loop copied last.ckpt to step<N>.ckpt at each validation, every 500 steps)
for env in mass_rope rigid_fall; do
  python -c "from vgpl.weight_averaging import trained_weights_checkpoint as t; t('checkpoints/sep/$env/inference/last.ckpt', 'checkpoints/sep/$env/inference/trained.ckpt')"
  python scripts/experiments/inferred_parameters.py --env $env checkpoints/sep/$env/inference/{last,trained}.ckpt
done
# both arms of each env on the 100 test videos, two evaluations at a time on one thread each (~8 min)
source "$(dirname "$0")/evaluate_two_encoders.sh"  # ev ENV ARM [ABLATION] [CURVE_VIDEOS]
for arm in last trained; do ev mass_rope $arm & ev rigid_fall $arm & wait; done
# the ablations that need no training of their own, on the EMA (~5 min each)
for ab in no_refinement no_params; do ev mass_rope last $ab 1 & ev rigid_fall last $ab 1 & wait; done
# MassRope was still improving: resumed alone on both cores for 20 more minutes (the timer carries over)
# python run.py env=mass_rope experiment=standard task=train_inference threads=2 model.inference.net.trajectory_start=both \
#     model.inference.net.separate_param_net=true model.inference.ema.decay=0.998 trainer.limit_val_batches=50 \
#     model.inference.trainer.max_steps=20000 model.inference.trainer.max_time=00:01:55:00 \
#     ckpt.dynamics=checkpoints/standard/mass_rope/dynamics/last.ckpt paths.ckpt_dir=checkpoints/sep/mass_rope \
#     hydra.run.dir=outputs/sep_inference_mass_rope_resumed ckpt_path=last
