#!/usr/bin/env bash
# RigidFall on one lent GPU (16 CPU cores), sized for one 10-minute device call (session 38):
#   V: the standard preset's visual stage on the 900 standard training videos, run 4.5 min on the
#      GPU (~10x the CPU's steps in the preset's 15 min), its clock-aware anneal over the last
#      third, then proposals exported (on the GPU) and read by the free-fall fit: how far does
#      GPU-scale training of the visual prior take the proposals' error on the standard data?
#   I: beside it, two inference modules trained on session 36's CPU prior and proposals (carried
#      in .carry/s36) at batch 2 (the preset) and 16: the P curve past the CPU's ~1,900 steps.
# The machine has no hydra/omegaconf: they travel as pure-Python packages in .carry/site
# (copied from this machine's site-packages: hydra, omegaconf, antlr4 and their dist-info), with
# session 36's dynamics prior folder (.carry/s36/dynamics: last.ckpt, config.yaml) and proposals
# (.carry/s36/proposals/{train,test}.h5); run it with carry [".carry"] and pipe it to $OUT.
# Measured in session 38 (423 s on an H200; docs/experiments.md, session 38).
# Usage (device): bash scripts/experiments/gpu_visual_scale.sh   [env: VIS_S=270 INF_S=330 GEN=1]
# Locally (smoke, on data/standard): GEN=0 VIS_S=20 INF_S=20 VIS_EXTRA="model.visual.max_rollouts=20" \
#   EXPORT_EXTRA="model.inference.max_rollouts=10 eval.max_rollouts=10" bash scripts/experiments/gpu_visual_scale.sh
set -uo pipefail
VIS_S=${VIS_S:-270}; INF_S=${INF_S:-330}; GEN=${GEN:-1}; VIS_EXTRA=${VIS_EXTRA:-}; EXPORT_EXTRA=${EXPORT_EXTRA:-}
source "$(dirname "$0")/device_preamble.sh"  # OUT, PYTHONPATH with .carry/site, PY, clock, stamp, nvidia-smi log
RUN=("$PY" run.py env=rigid_fall experiment=standard seed=0)  # an array: timeout cannot run a shell function

# data: the standard RigidFall set from seed 0 (session 36's shards, regenerated)
if [ "$GEN" = 1 ]; then
  stamp generate; timeout 200 "${RUN[@]}" task=generate data.processes=16 paths.data_dir=data/gpu hydra.run.dir=outputs/gpu_generate > outputs/gpu_logs/generate.txt 2>&1
  stamp "generate rc=$?"
else
  mkdir -p data/gpu/rigid_fall; for s in train test; do ln -sfn "$PWD/data/standard/rigid_fall/$s" data/gpu/rigid_fall/$s; done
fi
mkdir -p data/gpu_s36/rigid_fall/proposals
for s in train test; do ln -sfn "$PWD/data/gpu/rigid_fall/$s" data/gpu_s36/rigid_fall/$s; done
cp .carry/s36/proposals/*.h5 data/gpu_s36/rigid_fall/proposals/

# I: two inference modules on session 36's prior and proposals, side by side
for b in 2 16; do
  timeout $(( INF_S + 120)) "${RUN[@]}" task=train_inference threads=2 paths.data_dir=data/gpu_s36 \
    paths.ckpt_dir=checkpoints/gpu_b$b/rigid_fall ckpt.dynamics=.carry/s36/dynamics/last.ckpt model.inference.batch_size=$b \
    model.inference.trainer.max_steps=100000 model.inference.trainer.max_time=$(clock $INF_S) hydra.run.dir=outputs/gpu_inference_b$b \
    > outputs/gpu_logs/inference_b$b.txt 2>&1 &
done

# V: the visual stage, its proposals, the free-fall fit
stamp visual
timeout $(( VIS_S + 100)) "${RUN[@]}" task=train_visual threads=8 paths.data_dir=data/gpu paths.ckpt_dir=checkpoints/gpu_visual/rigid_fall \
  model.visual.stream_video=false model.visual.trainer.max_steps=30000 model.visual.net.lr_anneal_steps=10000 \
  model.visual.trainer.max_time=$(clock $VIS_S) model.visual.trainer.val_check_interval=3000 $VIS_EXTRA \
  hydra.run.dir=outputs/gpu_visual > outputs/gpu_logs/visual.txt 2>&1
stamp "visual rc=$?"
timeout 100 "${RUN[@]}" task=export_proposals threads=8 paths.data_dir=data/gpu paths.ckpt_dir=checkpoints/gpu_visual/rigid_fall $EXPORT_EXTRA hydra.run.dir=outputs/gpu_export > outputs/gpu_logs/export.txt 2>&1
stamp "export rc=$?"
for d in gpu gpu_s36; do
  timeout 60 "${RUN[@]}" task=free_fall_gravity paths.data_dir=data/$d hydra.run.dir=outputs/gpu_free_fall_$d > outputs/gpu_logs/free_fall_$d.txt 2>&1
  stamp "free fall ($d) rc=$?"
done
wait
stamp "all done"
tar czf "$OUT/gpu_results.tgz" outputs/gpu_* $(ls -d checkpoints/gpu_*/rigid_fall/*/tensorboard 2>/dev/null)
for f in outputs/gpu_*/metrics.json; do echo "== $f"; cat "$f"; echo; done
