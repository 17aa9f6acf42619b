#!/usr/bin/env bash
# Is the inference module's train/test gap in P the visual prior's? (issue 4; prepared in session 64, not yet run on a GPU)
# Every stage of the standard preset trains on the same first 900 videos, so the module learns P from proposals
# of videos the visual prior trained on. On FluidCube a GPU visual prior fit those 3x better than the test videos
# (session 59: 0.587 against 1.738 x 1e4), and the module read viscosity 15.8% on its videos, 23.8% on the test
# ones. RigidFall's best module reads gravity 3.22% on its 300 videos and 4.37% on the test ones (session 42);
# its proposals' gap was never measured. This call makes both arms of the comparison from ONE visual prior:
#   data  the standard ENV set from seed 0, with video (16 processes);
#   V     the standard visual stage on training videos 300-899 only (model.visual.first_rollout=300), held in
#         memory, on the clock, its last third annealed; then its proposals of training videos 0-599 and the
#         100 test videos. Videos 0-299 are held out (their proposals err as the test videos' do), 300-599
#         were seen. proposal_error_by_split.py --block 300 prints both blocks' error beside the test split's;
#   P     (PRIOR=1; MassRope's default, whose CPU prior is its limit: session 48) beside V, the env's standard
#         prior from nothing at batch 16 on the same clock, its 3 epochs written out in batch-16 steps.
# Back in $OUT: train_part0.npz (videos 0-299: held out), train_part1.npz (300-599: seen), test_part0.npz,
# [prior.ckpt], gpu_results.tgz. Then, on the CPU, the same prior and test proposals for both modules:
#   python scripts/experiments/proposals_parts.py unpack $F/train_part0.npz --to data/held_out/ENV/proposals/train.h5
#   python scripts/experiments/proposals_parts.py unpack $F/train_part1.npz --to data/seen/ENV/proposals/train.h5
#   (test_part0.npz into both; data/{held_out,seen}/ENV/{train,test} link the standard shards), then
#   python run.py task=train_inference env=ENV experiment=standard paths.data_dir=data/held_out ...   # and data/seen
# split_with_proposals takes any block of consecutive videos, so the seen arm trains on videos 300-599.
# Needs .carry/site (hydra, omegaconf, antlr4: pure Python, copied from this machine); carry [".carry"].
# Usage (device): ENV=rigid_fall bash scripts/experiments/gpu_held_out_visual.sh   [env: DEADLINE=480 PRIOR=0|1 GEN_N=1000 VAL=3000 V_EXTRA=]
# On a CPU, the preset's 15-minute visual stage on existing data (DATA holds <env>/{train,test}, linked, not generated):
#   ENV=rigid_fall DATA=/tmp/s64/data/standard DEADLINE=990 THREADS=2 STREAM=true PRIOR=0 EXPORT_S=900 OUT=/tmp/held_out bash scripts/experiments/gpu_held_out_visual.sh
# Locally (smoke): ENV=mass_rope GEN_N=40 HOLD=10 DEADLINE=150 VAL=50 THREADS=2 OUT=/tmp/gpu_out bash scripts/experiments/gpu_held_out_visual.sh
set -uo pipefail
ENV=${ENV:?ENV=rigid_fall or mass_rope}; DEADLINE=${DEADLINE:-480}; GEN_N=${GEN_N:-1000}; VAL=${VAL:-3000}; V_EXTRA=${V_EXTRA:-}
HOLD=${HOLD:-300}  # the module's videos: 0..HOLD-1 held out of the visual stage, HOLD..2 HOLD-1 seen by it
PRIOR=${PRIOR:-$([ "$ENV" = mass_rope ] && echo 1 || echo 0)}
DATA=${DATA:-}; THREADS=${THREADS:-12}; STREAM=${STREAM:-false}  # STREAM=true reads the videos window by window (the CPU preset's)
source "$(dirname "$0")/device_preamble.sh"  # OUT, PYTHONPATH with .carry/site, PY, clock, stamp, nvidia-smi log
RUN=("$PY" run.py env=$ENV experiment=standard seed=0 paths.data_dir=data/gpu)  # an array: timeout cannot run a shell function

if [ -n "$DATA" ]; then
  rm -rf data/gpu/$ENV; mkdir -p data/gpu/$ENV; for s in train test; do ln -sfn "$DATA/$ENV/$s" data/gpu/$ENV/$s; done
else
  stamp generate
  timeout 240 "${RUN[@]}" task=generate data.n_rollouts=$GEN_N data.processes=16 data.progress=false \
    hydra.run.dir=outputs/gpu_generate > outputs/gpu_logs/generate.txt 2>&1
  stamp "generate rc=$?"
fi
"$PY" scripts/experiments/data_fingerprint.py data/gpu $ENV > outputs/gpu_logs/fingerprint.json 2>&1 &

VIS_S=$(( DEADLINE - (SECONDS - t0) - 90 ))  # ~15 s to load the videos, ~50 s to test and export, ~20 s to pack
if [ "$PRIOR" = 1 ]; then  # the preset's 3 epochs of batch-4 steps (78,300) and noise-free finish (13,000) at batch 16
  stamp "prior clock ${VIS_S} s"
  timeout $(( VIS_S + 90 )) "${RUN[@]}" task=train_dynamics threads=4 paths.ckpt_dir=checkpoints/gpu_prior/$ENV \
    model.dynamics.batch_size=16 trainer.max_steps=19575 model.dynamics.net.noise_free_steps=3250 trainer.val_check_interval=$VAL \
    trainer.max_time=$(clock $VIS_S) trainer.enable_progress_bar=false hydra.run.dir=outputs/gpu_prior > outputs/gpu_logs/prior.txt 2>&1 &
fi
stamp "visual clock ${VIS_S} s"
timeout $(( VIS_S + 90 )) "${RUN[@]}" task=train_visual threads=$THREADS paths.ckpt_dir=checkpoints/gpu_visual/$ENV \
  model.visual.first_rollout=$HOLD model.inference.max_rollouts=$HOLD \
  model.visual.stream_video=$STREAM model.visual.trainer.max_steps=30000 model.visual.net.lr_anneal_steps=10000 \
  model.visual.trainer.max_time=$(clock $VIS_S) model.visual.trainer.val_check_interval=$VAL trainer.enable_progress_bar=false $V_EXTRA \
  hydra.run.dir=outputs/gpu_visual > outputs/gpu_logs/visual.txt 2>&1
stamp "visual rc=$?"
timeout ${EXPORT_S:-150} "${RUN[@]}" task=export_proposals threads=$THREADS data.progress=false paths.ckpt_dir=checkpoints/gpu_visual/$ENV \
  model.inference.max_rollouts=$(( 2 * HOLD )) hydra.run.dir=outputs/gpu_export > outputs/gpu_logs/export.txt 2>&1
stamp "export rc=$?"
START=$("$PY" -c "from omegaconf import OmegaConf; print(OmegaConf.load('conf/env/$ENV.yaml').start_frame)")  # the observed frames: START..START+9
"$PY" scripts/experiments/proposal_error_by_split.py data/gpu $ENV --block $HOLD --frames $START $(( START + 10 )) \
  > outputs/gpu_logs/proposal_error.txt 2>&1
for s in train test; do "$PY" scripts/experiments/proposals_parts.py pack data/gpu/$ENV/proposals/$s.h5 "$OUT" --rollouts $HOLD; done
wait
stamp "all done"
[ "$PRIOR" = 1 ] && cp checkpoints/gpu_prior/$ENV/dynamics/last.ckpt "$OUT/prior.ckpt"
tar czf "$OUT/gpu_results.tgz" outputs/gpu_* $(ls -d checkpoints/gpu_*/$ENV/*/{tensorboard,config.yaml} 2>/dev/null)
cat outputs/gpu_logs/fingerprint.json outputs/gpu_logs/proposal_error.txt; for f in outputs/gpu_*/metrics.json; do echo "== $f"; cat "$f"; echo; done
ls -la "$OUT"
