#!/usr/bin/env bash
# Issue 4, FluidCube (viscosity 20.6% against the paper's 17.5%). Session 45 found that MassRope's
# 4-frame priors ignore their stiffness input: they extrapolate the motion from the accelerations in
# their history (response slope 0.04 of the engine's; a 2-frame prior 0.90, oracle 14.6% -> 6.6%).
# Does FluidCube's prior read viscosity, a damping, from its history the same way? This measures
# the viscosity response (vgpl.eval.param_response; the fluid restarts exactly from a recorded frame,
# tests/eval/test_param_response.py) of the preset's 4-frame prior and of a 2-frame one trained on
# the same data for the same minutes, then their viscosity oracles.
# Run in session 62, both priors side by side on one core each (docs/experiments.md, session 62).
# Usage: bash scripts/experiments/fluid_cube_param_response.sh   # about 2 h 50 min on the 2-core CPU
#        ONLY_H4=1 bash ...                                       # stop after the 4-frame prior's response (about 1 h 15 min)
set -euo pipefail
O=outputs/fluid_cube_param_response
run() { python run.py env=fluid_cube experiment=standard "$@"; }
[[ -d data/standard/fluid_cube/test ]] || run task=generate hydra.run.dir=$O/generate          # 12.8-17.5 min, 1000 rendered videos (17.5 in session 47)
for H in 4 2; do
  CK=checkpoints/fluid_cube_h$H
  [[ -f $CK/fluid_cube/dynamics/last.ckpt ]] || run task=train_dynamics trainer.precision=bf16-mixed paths.ckpt_dir=$CK/fluid_cube \
    model.dynamics.history=$H hydra.run.dir=$O/prior_h$H                                        # 58 min
  python scripts/experiments/prior_param_response.py $CK/fluid_cube/dynamics/last.ckpt --json $O/param_response_h$H.json
  [[ -n "${ONLY_H4:-}" ]] && exit 0
done
for H in 4 2; do   # the viscosity oracle from the true frames and T+1..T+20 (100 test videos)
  run task=evaluate_dynamics ckpt_path=checkpoints/fluid_cube_h$H/fluid_cube/dynamics/last.ckpt eval.max_rollouts=100 hydra.run.dir=$O/oracle_h$H
done
