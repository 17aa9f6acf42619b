#!/usr/bin/env bash
# Session 23 (CPU, 2 cores, AMD EPYC), issue 4, FluidCube: why does viscosity not get learnt through
# the 40.2k-step prior (oracle 14.8% at horizon 5)? Needs session 22's checkpoints and data
# (scripts/experiments/fluid_cube_rerun.sh). As run, one thread per process:
#   A: session 22's run (one shared encoder, 823 steps) resumed; stopped by hand at 1,499 steps
#      (validation MAE rising 29 -> 34%); its timer carries over, hence the 20 extra minutes.
#   B: the paper's two encoders (separate_param_net=true) from scratch, with the weight EMA
#      (last.ckpt holds the averaged weights, trained.ckpt the trained ones): 2,272 steps.
#   the gradient of the rollout loss in viscosity over window starts 0-20 (20 test videos).
#   C: A's setup from scratch plus a supervised L1 on P (param_weight, NOT the paper): can the shared
#      encoder read viscosity at all? D: C with param_lr=1e-3 on P's head.
#   the probe and the readout diagnostics (python scripts in this folder).
# docs/experiments.md: "FluidCube: the paper's separate parameter encoder ..." (session 23).
set -euo pipefail
run() { python run.py env=fluid_cube experiment=standard "$@"; }
CK=checkpoints/standard/fluid_cube
SEP=checkpoints/sep/fluid_cube
mkdir -p /tmp/s23
common=(task=train_inference threads=1 model.inference.net.trajectory_start=both trainer.limit_val_batches=50
        model.inference.trainer.max_steps=20000 ckpt.dynamics=$CK/dynamics/last.ckpt)
run "${common[@]}" ckpt_path=last model.inference.trainer.max_time=00:02:15:00 \
    hydra.run.dir=outputs/fc_inference_resumed > /tmp/s23/armA.log 2>&1 &                  # killed at 1,499 steps
run "${common[@]}" model.inference.net.separate_param_net=true model.inference.ema.decay=0.998 \
    model.inference.trainer.max_time=00:01:55:00 paths.ckpt_dir=$SEP hydra.run.dir=outputs/fc_inference_sep > /tmp/s23/armB.log 2>&1 &
# (after A was stopped, on its core, one after the other)
#   cp $CK/inference/last.ckpt $CK/inference/step1499.ckpt
#   run task=evaluate_dynamics threads=1 eval.max_rollouts=20 task.param_grid=0 model.inference.net.horizon=5 \
#       'task.gradient_starts=[0,5,10,15,20]' ckpt_path=$CK/dynamics/last.ckpt hydra.run.dir=outputs/fc_gradient40k_h5   # 8 min
#   run task=evaluate ablation=full threads=1 eval.max_rollouts=100 eval.curve_rollouts=8 \
#       ckpt.inference=$CK/inference/step1499.ckpt hydra.run.dir=outputs/fc_evaluate_1499
#   for arm in supervised supervised_plr; do   # 25 min each; supervised_plr adds model.inference.net.param_lr=1e-3
#     run "${common[@]}" model.inference.net.param_weight=1.0 model.inference.trainer.max_time=00:00:25:00 \
#         paths.ckpt_dir=checkpoints/$arm/fluid_cube hydra.run.dir=outputs/fc_inference_$arm
#   done
#   python scripts/experiments/fluid_cube_viscosity_probe.py            # 1 min
#   python scripts/experiments/inferred_parameters.py --env fluid_cube $CK/inference/step1499.ckpt $SEP/inference/{last,trained}.ckpt checkpoints/supervised{,_plr}/fluid_cube/inference/last.ckpt
#   python scripts/experiments/fluid_cube_readout_through_prior.py 24 8 1e-2
wait
python -c "from vgpl.weight_averaging import trained_weights_checkpoint as t; t('$SEP/inference/last.ckpt', '$SEP/inference/trained.ckpt')"
evaluate=(task=evaluate ablation=full threads=1 eval.max_rollouts=100 eval.curve_rollouts=8
          ckpt.dynamics=$CK/dynamics/last.ckpt ckpt.visual=$CK/visual/last.ckpt paths.ckpt_dir=$SEP)
run "${evaluate[@]}" ckpt.inference=$SEP/inference/last.ckpt hydra.run.dir=outputs/fc_evaluate_sep_ema &
run "${evaluate[@]}" ckpt.inference=$SEP/inference/trained.ckpt hydra.run.dir=outputs/fc_evaluate_sep_trained &
wait
grep -h '"param_mae_pct\|"param_bias_pct\|future_mse_x1e4@20\|refine_mse' outputs/fc_evaluate_{1499,sep_ema,sep_trained}/metrics.json
# then B resumed 14 min on both cores (the timer carries over): 2,683 steps
#   run task=train_inference threads=2 model.inference.net.trajectory_start=both model.inference.net.separate_param_net=true \
#       model.inference.ema.decay=0.998 trainer.limit_val_batches=50 model.inference.trainer.max_steps=20000 \
#       model.inference.trainer.max_time=00:02:09:00 ckpt.dynamics=$CK/dynamics/last.ckpt paths.ckpt_dir=$SEP ckpt_path=last \
#       hydra.run.dir=outputs/fc_inference_sep_resumed
