#!/usr/bin/env bash
# Session 46 (CPU, 2 cores, AMD EPYC), issue 4, MassRope: the four-way study through the 2-frame
# prior of session 45 (scripts/experiments/mass_rope_history2.sh), once its inference module has
# its preset's 3,000 steps (resumed: ckpt_path=last ... max_time). The w/o-rigidness module starts
# from the full one's weights (a fine-tune of MIN minutes: more training than the full module had,
# so a win for VGPL is not one of steps).
# Usage: bash scripts/experiments/mass_rope_h2_fourway.sh [MIN=25]   # 59 min with 25 (session 46)
#   CK=<ckpt_dir> O=<output dir> bash ...   study another module through the same prior (session 47:
#   CK=checkpoints/s46_h2_long/mass_rope O=outputs/s47_fourway with MIN=20, the module continued to
#   5,750 steps; 55 min. Session 48: CK=checkpoints/s48_module/mass_rope O=outputs/s48_fourway with MIN=12,
#   the module through the H100-trained prior; 50 min)
#   D=<data dir> reads proposals exported elsewhere (session 49: D=data/s49 CK=checkpoints/s49/mass_rope, the
#   50-minute visual prior's proposals; default data/standard)
#   POOL=mean trains the w/o-rigidness module on window-pooled proposals (model.inference.window_pool; session 51:
#   D=data/s51 CK=checkpoints/s51/mass_rope POOL=mean). The evaluations take each module's own pool from its checkpoint.
set -euo pipefail
CK=${CK:-checkpoints/s45_h2/mass_rope}
O=${O:-outputs/s46_fourway}
D=${D:-data/standard}
POOL=${POOL:-last}
MIN=${1:-25}
run() { python run.py env=mass_rope experiment=standard paths.data_dir=$D paths.ckpt_dir=$CK "$@"; }
run task=evaluate ablation=full eval.error_sources=true hydra.run.dir=$O/full
for A in no_params no_refinement; do
  run task=evaluate ablation=$A eval.rigidness_curve_from=$O/full/metrics.json hydra.run.dir=$O/$A
done
[[ -f $CK/inference_no_rigidness/last.ckpt ]] || run task=train_inference ablation=no_rigidness \
  model.inference.init_from=$CK/inference/last.ckpt model.inference.trainer.max_time=00:00:$MIN:00 model.inference.window_pool=$POOL \
  hydra.run.dir=$O/train_no_rigidness
run task=evaluate ablation=no_rigidness eval.error_sources=true hydra.run.dir=$O/no_rigidness
python run.py task=report task.dir=$O hydra.run.dir=$O/report
