# Sourced by the scripts that run on a lent GPU machine (gpu_*.sh): $OUT (what comes back) and
# outputs/gpu_logs, the carried packages (.carry/site: hydra, omegaconf, antlr4, which that machine
# lacks) on PYTHONPATH, $PY, clock SECONDS (-> trainer.max_time), stamp MESSAGE (seconds since the
# start), the GPU's name, and its use every 15 s in outputs/gpu_logs/smi.csv.
OUT=${OUT:-/tmp/gpu_out}; mkdir -p "$OUT" outputs/gpu_logs
export PYTHONPATH=$PWD/src:$PWD/.carry/site${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
PY=$(command -v python3)
clock() { printf '00:00:%02d:%02d' $(( $1 / 60 )) $(( $1 % 60 )); }  # seconds -> trainer.max_time
t0=$SECONDS; stamp() { echo "[t=$((SECONDS - t0))s] $*"; }
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader 2>/dev/null
(nvidia-smi --query-gpu=timestamp,utilization.gpu,memory.used --format=csv -l 15 > outputs/gpu_logs/smi.csv 2>/dev/null &)
