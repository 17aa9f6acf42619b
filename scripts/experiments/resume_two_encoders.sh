#!/usr/bin/env bash
# Session 25 (CPU, 2 cores, AMD EPYC), issue 4: the two-encoder inference modules of sessions 23
# (FluidCube, arm B, 2,683 steps) and 24 (MassRope, 3,436 steps) were still improving; both resumed
# side by side on one thread each for 100 more minutes (the timers carry over: 2:09 and 1:55 used),
# now validating on the evaluation's window (val_window_span=0, standard preset). Then both arms of
# each (EMA = last.ckpt, trained weights) through task=evaluate on the 100 test videos, and MassRope's
# training-free ablations. Needs sessions 22-24's checkpoints (fluid_cube_inference_long.sh,
# separate_param_net.sh). README: "Resumed two-encoder runs ..." (session 25).
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
ev() { # env arm [ablation, full] [curve videos, 8]
  CK=checkpoints/standard/$1
  python run.py env=$1 experiment=standard task=evaluate ablation=${3:-full} eval.max_rollouts=100 eval.curve_rollouts=${4:-8} threads=1 \
    paths.ckpt_dir=checkpoints/sep/$1 ckpt.dynamics=$CK/dynamics/last.ckpt ckpt.visual=$CK/visual/last.ckpt \
    ckpt.inference=checkpoints/sep/$1/inference/$2.ckpt hydra.run.dir=outputs/s25_evaluate_$1_${3:-$2} > /tmp/s25_evaluate_$1_${3:-$2}.log 2>&1
}
for arm in last trained; do ev fluid_cube $arm & ev mass_rope $arm & wait; done
ev mass_rope last no_params 1
