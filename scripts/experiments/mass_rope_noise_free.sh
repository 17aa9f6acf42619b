#!/usr/bin/env bash
# Session 43 (CPU, 2 cores, AMD EPYC), issue 4, MassRope. Session 41 found RigidFall's prior biased by
# its history noise (it shrinks fast velocities, so every rollout fits a wrong gravity) and the
# standard preset now ends the prior without it (model.dynamics.net.noise_free_steps, session 42).
# MassRope's stiffness oracle was 11.8% in session 21 (paper: 2.9% from video), and its module's
# stiffness is shrunk towards the middle: does the noise-free finish pin stiffness down too?
# The standard chain from nothing, each stage alone on both cores: the oracle on the last snapshot
# before the noise-free finish (step50000.ckpt) and on the finished prior, then the visual stage,
# the proposals, the full inference module and the three ablations that need no module of their own.
# Usage: bash scripts/experiments/mass_rope_noise_free.sh            # everything, about 2 h 15 min
#        SKIP_PRIOR=1 bash scripts/experiments/mass_rope_noise_free.sh  # the prior already trained
set -euo pipefail
run() { python run.py env=mass_rope experiment=standard "$@"; }
CK=checkpoints/standard/mass_rope
O=outputs/s43
if [[ -z "${SKIP_PRIOR:-}" ]]; then
  run task=generate hydra.run.dir=$O/generate_mass_rope                                   # 75 s, 1000 videos
  run task=train_dynamics trainer.precision=bf16-mixed model.dynamics.snapshot_every_n_steps=10000 hydra.run.dir=$O/prior_mass_rope   # 58 min
fi
for ckpt in step50000 last; do   # 100 test videos, 9 + 9 stiffness values each, from the true frames
  run task=evaluate_dynamics ckpt_path=$CK/dynamics/$ckpt.ckpt eval.max_rollouts=100 hydra.run.dir=$O/oracle_$ckpt
done
run task=train_visual hydra.run.dir=$O/visual                                               # 15 min cap
run task=export_proposals hydra.run.dir=$O/export
run task=train_inference hydra.run.dir=$O/inference                                         # 25 min cap
run task=evaluate ablation=full eval.curve_rollouts=8 hydra.run.dir=$O/evaluate/full
python run.py -m task=evaluate env=mass_rope experiment=standard ablation=no_params,no_refinement eval.curve_rollouts=1 \
  hydra.sweep.dir=$O/evaluate hydra.sweep.subdir='${ablation.name}'
