#!/usr/bin/env bash
# Session 22 (CPU, 2 cores, AMD EPYC), issue 4, FluidCube: the standard chain rerun from scratch with
# the recipes of sessions 15-21 (the streamed visual prior on all 900 training videos, P learnt from
# the true start with trajectory_start=both), and the identifiability oracle checked at each prior stop.
# FluidCube had not been run since session 6 (viscosity 25.2% from video against the paper's 17.5%).
# As run. Usage: bash scripts/experiments/fluid_cube_rerun.sh
set -euo pipefail
run() { python run.py env=fluid_cube experiment=standard "$@"; }
CK=checkpoints/standard/fluid_cube
# the viscosity oracle of the current prior on 20 test videos (README: design, "a floor for parameter grounding")
oracle() { run task=evaluate_dynamics eval.max_rollouts=20 task.param_grid=9 ckpt_path=$CK/dynamics/last.ckpt "$@"; }
run task=generate data.processes=2 hydra.run.dir=outputs/fc_generate                     # 1000 rendered rollouts
# core 1: the dynamics prior (session 4's recipe, bf16-mixed) on one thread for its first 27 minutes
run task=train_dynamics threads=1 trainer.precision=bf16-mixed trainer.max_time=00:00:27:00 \
    hydra.run.dir=outputs/fc_prior > /tmp/fc_prior.log 2>&1 &
# core 2 meanwhile: the visual prior (streamed, all 900 videos) and its proposals
run task=train_visual threads=1 model.visual.trainer.max_time=00:00:21:00 \
    '+model.visual.trainer.precision=${fast_precision:bf16-mixed}' hydra.run.dir=outputs/fc_visual
run task=export_proposals threads=1 hydra.run.dir=outputs/fc_export
wait
# the prior resumed alone on both cores (the timer carries over) to 55 minutes in all
run task=train_dynamics threads=2 trainer.precision=bf16-mixed ckpt_path=last trainer.max_time=00:00:55:00 \
    hydra.run.dir=outputs/fc_prior_resumed
# The identifiability check on this 22.9k-step prior (20 test videos, the 15-frame horizon); the
# gradient agreement was stopped after its first window start (its line is in the run's log)
oracle threads=2 'task.gradient_starts=[0,10,20]' model.inference.net.horizon=15 hydra.run.dir=outputs/fc_oracle_h15
cp $CK/dynamics/last.ckpt $CK/dynamics/step22883.ckpt
# every argmin at the most viscous end (oracle 44.2% against 29.1%): the prior resumed to 90 minutes in all
run task=train_dynamics threads=2 trainer.precision=bf16-mixed ckpt_path=last trainer.max_time=00:01:30:00 \
    hydra.run.dir=outputs/fc_prior_resumed2
cp $CK/dynamics/last.ckpt $CK/dynamics/step40186.ckpt
# the identifiability check on the 40.2k-step prior at both horizons, one thread each, side by side (~3 min)
for h in 5 15; do
  oracle threads=1 model.inference.net.horizon=$h hydra.run.dir=outputs/fc_oracle40k_h$h &
done; wait
# the inference module (the standard 5-frame horizon, P from the true start), 20 min on both cores
run task=train_inference threads=2 model.inference.net.trajectory_start=both trainer.limit_val_batches=50 \
    model.inference.trainer.max_time=00:00:20:00 hydra.run.dir=outputs/fc_inference
run task=evaluate ablation=full threads=2 eval.max_rollouts=100 eval.curve_rollouts=8 hydra.run.dir=outputs/fc_evaluate
