# Sourced by separate_param_net.sh and resume_two_encoders.sh: task=evaluate of a two-encoder
# inference checkpoint checkpoints/sep/<env>/inference/<arm>.ckpt on the 100 test videos, on one
# thread, with the standard priors and visual prior of <env>; writes outputs/<PREFIX>_<env>_<ablation or arm>.
# ev ENV ARM [ABLATION, full] [CURVE_VIDEOS, 8]; PREFIX (default sep_evaluate) names the run folders.
ev() {
  local ck=checkpoints/standard/$1 name=${PREFIX:-sep_evaluate}_$1_${3:-$2}
  python run.py env=$1 experiment=standard task=evaluate ablation=${3:-full} eval.max_rollouts=100 eval.curve_rollouts=${4:-8} threads=1 \
    paths.ckpt_dir=checkpoints/sep/$1 ckpt.dynamics=$ck/dynamics/last.ckpt ckpt.visual=$ck/visual/last.ckpt \
    ckpt.inference=checkpoints/sep/$1/inference/$2.ckpt hydra.run.dir=outputs/$name > /tmp/$name.log 2>&1
}
