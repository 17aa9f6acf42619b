#!/usr/bin/env bash
# Session 58 (CPU, 2 cores, AMD EPYC), issue 4: FluidCube observed from frame 20, after the cube has
# settled into the fluid (it sinks until about frame 16), with session 57's bernoulli module (trained
# on windows from frames 10-20), and the w/o rigidness module that the four-way study lacked: session
# 56's 1,442-step module continued with Q = 0 to the same 2,783 steps as session 57's bernoulli arm
# (the same start, optimiser state and step budget). docs/experiments.md: "session 58".
#
# ROOT holds data -> session 54's data (H200 proposals, 30 frames), checkpoints/standard/fluid_cube/
# {dynamics: session 56's projected prior, inference: session 57's bernoulli module,
# inference_no_rigidness: a copy of session 56's 1,442-step module}.
# Usage: bash scripts/experiments/fluid_cube_frame20.sh ROOT
set -euo pipefail
ROOT=$1
COMMON="env=fluid_cube experiment=standard paths.root_dir=$ROOT"
python run.py $COMMON task=train_inference ablation=no_rigidness env.start_frame=10 model.inference.window_span=10 \
  ckpt_path=last model.inference.trainer.max_steps=2783 model.inference.trainer.max_time=00:01:55:00
# the exported proposals cover frames 0-29: from frame 20 the observation (and the rigidness curve) ends at T = 10
EVAL="$COMMON task=evaluate eval.proposals=exported env.start_frame=20 eval.max_observed=10"
python run.py $EVAL ablation=full hydra.run.dir=$ROOT/eval_full_f20
python run.py -m $EVAL ablation=no_refinement,no_params,no_rigidness hydra.sweep.dir=$ROOT/ablate_f20
python run.py task=report "task.dir=[$ROOT/eval_full_f20,$ROOT/ablate_f20]" hydra.run.dir=$ROOT/report_f20
