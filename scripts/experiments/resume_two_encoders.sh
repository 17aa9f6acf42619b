#!/usr/bin/env bash
# Session 25 (CPU, 2 cores, AMD EPYC), issue 4: the two-encoder inference modules of sessions 23
# (FluidCube, arm B, 2,683 steps) and 24 (MassRope, 3,436 steps) were still improving; both resumed
# side by side on one thread each for 100 more minutes (the timers carry over: 2:09 and 1:55 used),
# now validating on the evaluation's window (val_window_span=0, standard preset). Then both arms of
# each (EMA = last.ckpt, trained weights) through task=evaluate on the 100 test videos, and MassRope's
# training-free ablations. Needs sessions 22-24's checkpoints (fluid_cube_inference_long.sh,
# separate_param_net.sh). docs/experiments.md: "Resumed two-encoder runs ..." (session 25).
set -euo pipefail
common=(experiment=standard task=train_inference threads=1 model.inference.net.trajectory_start=both
        model.inference.net.separate_param_net=true model.inference.ema.decay=0.998 trainer.limit_val_batches=50
        model.inference.trainer.max_steps=20000 model.inference.snapshot_every_n_steps=500 ckpt_path=last)
# (as run in session 25, step<N>.ckpt were copied from last.ckpt by a loop; snapshot_every_n_steps does it now)
python run.py env=fluid_cube "${common[@]}" model.inference.trainer.max_time=00:03:49:00 \
    ckpt.dynamics=checkpoints/standard/fluid_cube/dynamics/last.ckpt paths.ckpt_dir=checkpoints/sep/fluid_cube \
    hydra.run.dir=outputs/s25_fc_resumed > /tmp/s25_fc.log 2>&1 &
python run.py env=mass_rope "${common[@]}" model.inference.trainer.max_time=00:03:35:00 \
    ckpt.dynamics=checkpoints/standard/mass_rope/dynamics/last.ckpt paths.ckpt_dir=checkpoints/sep/mass_rope \
    hydra.run.dir=outputs/s25_mr_resumed > /tmp/s25_mr.log 2>&1 &
wait
for env in fluid_cube mass_rope; do
  python -c "from vgpl.weight_averaging import trained_weights_checkpoint as t; t('checkpoints/sep/$env/inference/last.ckpt', 'checkpoints/sep/$env/inference/trained.ckpt')"
done
PREFIX=s25_evaluate
source "$(dirname "$0")/evaluate_two_encoders.sh"  # ev ENV ARM [ABLATION] [CURVE_VIDEOS]
for arm in last trained; do ev fluid_cube $arm & ev mass_rope $arm & wait; done
ev mass_rope last no_params 1 & ev mass_rope last no_refinement 1 & wait
