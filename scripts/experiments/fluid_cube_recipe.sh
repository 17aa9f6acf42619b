#!/usr/bin/env bash
# Session 59 (issue 4): FluidCube's frame-20 recipe on proposals that cover the whole observation.
# Session 58 read viscosity 16.5% observing from frame 20, through session 54's proposals, which end at
# frame 29 (the rigidness curve stopped at T = 10). docs/experiments.md: "session 59".
#   1. on a lent H200 (one call, 466 s): the first 60 frames of the standard data, the visual stage from
#      frame 20 (26,581 steps in 330 s) and its proposals of frames 0-39, as float16 parts:
#        bash scripts/experiments/gpu_fluid_cube_frame20.sh            (run with carry [".carry"])
#   2. here (2-core CPU): ROOT/data/standard/fluid_cube/{train,test} are the standard data (task=generate),
#      ROOT/checkpoints/standard/fluid_cube/dynamics session 56's projected prior, PARTS the call's files,
#      S57 session 57's bernoulli module (last.ckpt).
# Usage: bash scripts/experiments/fluid_cube_recipe.sh ROOT PARTS S57   [env: ROOT60=... for session 60's part]
set -euo pipefail
ROOT=$1; PARTS=$2; S57=$3
COMMON="env=fluid_cube experiment=standard paths.root_dir=$ROOT env.start_frame=20 env.rigid_head=projected model.inference.window_span=10"
for s in train test; do
  python scripts/experiments/proposals_parts.py unpack "$PARTS"/${s}_part*.npz --to "$ROOT/data/standard/fluid_cube/proposals/$s.h5"
done
# what the prior allows from frame 20 (true frames, 20 test videos): viscosity and the cube's rigidness
python run.py $COMMON task=evaluate_dynamics ckpt_path=$ROOT/checkpoints/standard/fluid_cube/dynamics/last.ckpt eval.max_rollouts=20 \
  task.start_frame=20 hydra.run.dir=$ROOT/sweep_f20
# the module from nothing with bernoulli Q: the cube's Q fell to 0.02 by step 99 and 0.001 by 699 (stopped at 750)
python run.py $COMMON task=train_inference model.inference.net.rigidness_estimator=bernoulli model.inference.trainer.max_time=00:01:35:00 &
pid=$!; sleep 2100; kill $pid; wait $pid || true
mv $ROOT/checkpoints/standard/fluid_cube/inference $ROOT/checkpoints/standard/fluid_cube/inference_scratch_bernoulli
# session 57's module (blend 1,442 steps from frame 10, then bernoulli to 2,783) fine-tuned 55 min on windows from frames 20-30
python run.py $COMMON task=train_inference model.inference.net.rigidness_estimator=bernoulli model.inference.init_from=$S57 \
  model.inference.trainer.max_time=00:00:55:00
EVAL="$COMMON task=evaluate eval.proposals=exported"
python run.py $EVAL ablation=full hydra.run.dir=$ROOT/eval_full
python run.py $EVAL ablation=full ckpt.inference=$S57 hydra.run.dir=$ROOT/eval_s57     # the module unchanged, on these proposals
# P on the training and the test videos from frame 20, and the proposals' error on each
python scripts/experiments/param_by_window_start.py $ROOT/checkpoints/standard/fluid_cube/inference/last.ckpt 20 -- env=fluid_cube experiment=standard paths.root_dir=$ROOT
python scripts/experiments/proposal_error_by_split.py $ROOT/data/standard fluid_cube
# Session 60 (docs/experiments.md, "session 60"): the module above fine-tuned 50 min on jittered proposals (952 steps),
# into a root of its own (ROOT60: the same data, proposals and prior, linked), then read under added jitter
if [ -n "${ROOT60:-}" ]; then
  COMMON60="env=fluid_cube experiment=standard paths.root_dir=$ROOT60 env.start_frame=20 env.rigid_head=projected model.inference.window_span=10"
  python run.py $COMMON60 task=train_inference model.inference.net.rigidness_estimator=bernoulli \
    model.inference.init_from=$ROOT/checkpoints/standard/fluid_cube/inference/last.ckpt model.inference.net.proposal_noise=0.002 \
    model.inference.trainer.max_time=00:00:50:00
  python run.py $COMMON60 task=evaluate eval.proposals=exported ablation=full hydra.run.dir=$ROOT60/eval_full
  python scripts/experiments/param_under_jitter.py $ROOT60/checkpoints/standard/fluid_cube/inference/last.ckpt test 20 0 0.5 1 2 -- $COMMON60
fi
