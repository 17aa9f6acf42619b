#!/usr/bin/env bash
# MassRope on one lent GPU (16 CPU cores), sized for one 10-minute device call (session 48), issue 4.
# Session 47's module reads stiffness 7.5%, within a point of its prior's own oracle (6.6%): the
# 2-frame prior (session 45, checkpoints/s45_h2, 29,381 steps in 58 CPU minutes, stopped 3k steps
# past its first lr drop) is now the limit. Here it is trained on from its weights
# (model.dynamics.init_from: fresh optimiser and clock), three ways side by side on the one GPU:
#   lr9e5_b4   the preset's batch 4 at the rate it had reached (9e-5, constant), history noise
#              for the first two thirds of the clock, the last third noise-free (as the preset ends);
#   lr18e5_b16 the same at batch 16 and twice the rate: four times the windows a step;
#   nf3e5_b4   noise-free all through at 3e-5: only a longer version of the preset's finish.
# Each gets TRAIN_S seconds. The checkpoints come back in $OUT and are measured on the CPU with
# prior_param_response.py and task=evaluate_dynamics (the oracle) before a module is trained through one.
# The machine has no hydra/omegaconf: they travel as pure-Python packages in .carry/site (copied
# from this machine's site-packages: hydra, omegaconf, antlr4 and their dist-info), with the
# prior's last.ckpt and config.yaml in .carry/s45_h2; run it with carry [".carry"].
# ROUND=2 (on the same warm machine, whose data/gpu and checkpoints/gpu_* stay) trains each on from
# its own round-1 weights in the same way into checkpoints/gpu_<name>_r2, and skips the generation.
# Measured in session 48 on one H100 (docs/experiments.md, session 48): the generation 21 s; round 1
# 330 s, 11.7-12.1k steps each (about 36 steps/s, three processes sharing the GPU); round 2 230 s,
# 8.6-8.8k steps. Best, by the linearised stiffness oracle of prior_param_response.py (50 test
# videos, on the CPU): lr18e5_b16_r2, 1.3% (session 45's prior: 4.7% at 100 videos).
# Usage (device): bash scripts/experiments/gpu_mass_rope_prior.sh      [env: TRAIN_S=330 GEN_N=1000 ROUND=1]
#                 then ROUND=2 TRAIN_S=230 bash scripts/experiments/gpu_mass_rope_prior.sh
# Locally (smoke): TRAIN_S=20 GEN_N=20 VAL=50 bash scripts/experiments/gpu_mass_rope_prior.sh
set -uo pipefail
TRAIN_S=${TRAIN_S:-330}; GEN_N=${GEN_N:-1000}; ROUND=${ROUND:-1}; VAL=${VAL:-2000}  # validate every VAL steps (batch 16 has 6,525 a pass)
source "$(dirname "$0")/device_preamble.sh"  # OUT, PYTHONPATH with .carry/site, PY, clock, stamp, nvidia-smi log
RUN=("$PY" run.py env=mass_rope experiment=standard seed=0)  # an array: timeout cannot run a shell function

# data: the standard MassRope set from seed 0, particles only (the prior reads no video)
if [ "$ROUND" = 1 ]; then
stamp generate
timeout 150 "${RUN[@]}" task=generate data.render=false data.n_rollouts=$GEN_N data.processes=16 data.progress=false \
  paths.data_dir=data/gpu hydra.run.dir=outputs/gpu_generate > outputs/gpu_logs/generate.txt 2>&1
stamp "generate rc=$?"
fi

# three continuations of session 45's prior (round 2: of round 1's), side by side
train() {  # name lr batch noise
  local name=$1 init=.carry/s45_h2/last.ckpt
  [ "$ROUND" = 1 ] || { init=checkpoints/gpu_$1/mass_rope/dynamics/last.ckpt; name=$1_r$ROUND; }
  timeout $(( TRAIN_S + 120 )) "${RUN[@]}" task=train_dynamics threads=4 paths.data_dir=data/gpu \
    paths.ckpt_dir=checkpoints/gpu_$name/mass_rope model.dynamics.init_from=$init \
    model.dynamics.batch_size=$3 model.dynamics.net.lr=$2 model.dynamics.net.lr_decay=1.0 model.dynamics.net.noise=$4 \
    model.dynamics.net.noise_free_steps=33000 trainer.max_steps=100000 trainer.max_epochs=-1 trainer.val_check_interval=$VAL +trainer.check_val_every_n_epoch=null trainer.max_time=$(clock $TRAIN_S) \
    trainer.enable_progress_bar=false hydra.run.dir=outputs/gpu_$name > outputs/gpu_logs/train_$name.txt 2>&1
  stamp "train $name rc=$?"
}
train lr9e5_b4 9e-5 4 0.05 &
train lr18e5_b16 1.8e-4 16 0.05 &
train nf3e5_b4 3e-5 4 0.0 &
wait
stamp "all done"
sfx=; [ "$ROUND" = 1 ] || sfx=_r$ROUND
for n in lr9e5_b4$sfx lr18e5_b16$sfx nf3e5_b4$sfx; do
  cp checkpoints/gpu_$n/mass_rope/dynamics/last.ckpt "$OUT/$n.ckpt" 2>/dev/null
  echo "== $n"; grep -h -i "stopped\|steps\"\|val" outputs/gpu_logs/train_$n.txt | tail -4
done
tar czf "$OUT/gpu_results$sfx.tgz" outputs/gpu_* $(ls -d checkpoints/gpu_*/mass_rope/dynamics/{tensorboard,config.yaml} 2>/dev/null)
