#!/usr/bin/env bash
# Session 44 (CPU, 2 cores, AMD EPYC), issue 4, MassRope. Session 43 found MassRope's prior unbiased
# (sphere acceleration slope 1.006) but its stiffness oracle and T+20 swinging between checkpoints of
# one run more than any change to the recipe moved them (oracle 14.6% at step50000, 18.6% at the end,
# 24.1% for an equal-steps control; T+20 5.6 / 11.0 / 17.8 / 30.2). Does an exponential moving average
# of the prior's weights (model.dynamics.ema.decay, the same callback as the inference module's) steady
# them? One run answers it paired: every snapshot holds the average (state_dict) and the weights being
# trained (current_model_state), so the raw and averaged priors are compared at the same steps.
# As run (docs/experiments.md, session 44): the prior reached 32,362 steps (9.3 steps/s in bf16 on this
# session's machine, half session 43's). The average steadied T+20 (17.4 / 17.3 / 12.0 / 11.8 at 10k /
# 20k / 30k / the end, raw 74.4 / 15.2 / 47.5 / 45.8) but not the stiffness oracle: 16.1% (bias -12.8)
# at the end against the raw 14.6% (-8.3), 31.6% (-28.9) at 20k; it shrinks the one-step acceleration
# (sphere slope 0.944 against 1.007), so it reads every rope as softer. The option stays off.
# Usage: bash scripts/experiments/mass_rope_prior_ema.sh              # about 1 h 50 min
#        SKIP_PRIOR=1 bash scripts/experiments/mass_rope_prior_ema.sh  # the prior already trained
set -euo pipefail
run() { python run.py env=mass_rope experiment=standard "$@"; }
CK=checkpoints/standard/mass_rope/dynamics
O=outputs/s44
if [[ -z "${SKIP_PRIOR:-}" ]]; then
  run task=generate hydra.run.dir=$O/generate_mass_rope                                          # 75 s, 1000 videos
  run task=train_dynamics trainer.precision=bf16-mixed model.dynamics.snapshot_every_n_steps=10000 \
    model.dynamics.ema.decay=0.9998 hydra.run.dir=$O/prior_mass_rope                            # 58 min; an average over ~5,000 steps
fi
# the weights being trained, beside each averaged snapshot (the folder's config.yaml loads both)
SNAPS=$(cd $CK && ls step*.ckpt | sort -V | sed 's/.ckpt$//') ; SNAPS="$SNAPS last"   # 10k, 20k, ... as far as the run got
python -c "
import sys
from vgpl.weight_averaging import trained_weights_checkpoint as t
for c in sys.argv[2:]:
    t(f'{sys.argv[1]}/{c}.ckpt', f'{sys.argv[1]}/raw_{c}.ckpt')" $CK $SNAPS   # one torch import for every snapshot
# rollouts only (T+1..T+20 on 100 test videos, ~1 min each)
for c in $SNAPS; do
  for w in "" raw_; do
    run task=evaluate_dynamics ckpt_path=$CK/$w$c.ckpt eval.max_rollouts=100 task.param_grid=0 hydra.run.dir=$O/rollouts_$w$c
  done
done
# the stiffness oracle (9 + 9 values from the true frames, 100 test videos, 13 min each)
for w in "" raw_; do
  run task=evaluate_dynamics ckpt_path=$CK/${w}last.ckpt eval.max_rollouts=100 hydra.run.dir=$O/oracle_${w}last
done
python scripts/experiments/prior_acceleration_slope.py $CK/last.ckpt $CK/raw_last.ckpt
# then the oracle at step 20,000 too, before the noise-free finish (13 min each)
for w in "" raw_; do
  run task=evaluate_dynamics ckpt_path=$CK/${w}step20000.ckpt eval.max_rollouts=100 hydra.run.dir=$O/oracle_${w}step20000
done
python scripts/experiments/prior_acceleration_slope.py $CK/step20000.ckpt $CK/raw_step20000.ckpt
