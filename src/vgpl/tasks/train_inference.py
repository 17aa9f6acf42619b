"""task=train_inference: train the InferenceModule through the frozen DynamicsPrior, on the
VisualPrior's exported proposals. ``ablation=no_rigidness`` trains the variant that treats
every instance as non-rigid; the other ablations are evaluation-time switches."""

from __future__ import annotations

import json
import logging
from pathlib import Path

from omegaconf import DictConfig

from vgpl.checkpoint import init_from_spec, load_stage, scene_of
from vgpl.data.inference_windows import InferenceDataModule
from vgpl.models.dynamics_prior import DynamicsPrior
from vgpl.models.inference import InferenceModule, instantiated
from vgpl.models.rollout_target import ProposalsTarget, rollout_target
from vgpl.tasks.stage import dynamics_stage, fit, setup_run, stage_checkpoint, stopping, validate_final

log = logging.getLogger(__name__)


def inference_stage(ablation: DictConfig) -> str:
    """Checkpoint folder of the inference module an ablation uses: the full module, or the one
    trained with Q = 0 through the rigid prior (no_rigidness) or through the unconstrained prior
    (no_rigidness_unconstrained)."""
    if ablation.rigidness:
        return "inference"
    return "inference_no_rigidness_unconstrained" if ablation.get("unconstrained_prior") else "inference_no_rigidness"


def ablation_prior(ablation: DictConfig) -> str:
    """Checkpoint folder of the dynamics prior an ablation rolls."""
    return dynamics_stage(bool(ablation.get("unconstrained_prior")))


def inference_datamodule(cfg: DictConfig, scene) -> InferenceDataModule:
    """The inference module's windows as ``cfg.model.inference`` and ``cfg.env`` set them (not yet set up)."""
    spec = cfg.model.inference
    return InferenceDataModule(cfg.data.root, scene, spec.observed, spec.horizon, spec.batch_size, cfg.env.get("start_frame", 0),
                               spec.window_stride, spec.get("window_span"), val_span=spec.get("val_window_span"),
                               window_pool=spec.get("window_pool", "last"), target_proposals=rollout_target(spec.net) == ProposalsTarget.name)


def inference_module(cfg: DictConfig, scene) -> InferenceModule:
    """The InferenceModule ``model.inference.net`` composes, for ``scene`` and the ablation's rigidness; its parts are built
    by the module from their configs, so the checkpoint's hyperparameters are plain config."""
    spec = cfg.model.inference
    given = {"param_low": scene.param_low.tolist(), "param_high": scene.param_high.tolist(), "n_particles": scene.n_particles,
             "n_instances": scene.n_instances, "radius": float(cfg.env.graph_radius), "instance_types": list(scene.instance_types)}
    return instantiated(spec.net, _convert_="all", _recursive_=False, scene=given, horizon=int(spec.horizon), rigidness=bool(cfg.ablation.rigidness))


def train_inference(cfg: DictConfig) -> dict:
    setup_run(cfg)
    scene = scene_of(cfg)
    spec = cfg.model.inference
    if spec.net.encoder.get("param_rotation") and not scene.vertical_symmetry:
        raise ValueError(f"model.inference.net.encoder.param_rotation=true: env={scene.name} is not symmetric about the vertical axis "
                         f"(planes or sampling that a rotation would change); only RigidFall is")
    dynamics, _ = load_stage(stage_checkpoint(cfg, ablation_prior(cfg.ablation)), DynamicsPrior, env=scene.name)
    dm = inference_datamodule(cfg, scene)
    dm.setup()
    source = {"proposals_source": str(dm.train_proposals.attrs.get("source", "visual")),
              "proposals_noise_std": float(dm.train_proposals.attrs.get("noise_std", 0.0))}
    if source["proposals_source"] != "visual":
        log.warning("training on %s proposals (noise std %g m, task=export_proposals task.source=truth): a diagnostic, not the paper's VGPL",
                    source["proposals_source"], source["proposals_noise_std"])
    model = inference_module(cfg, scene)
    model.set_stats(dynamics)  # the same units as the prior it is trained through
    model.attach_dynamics(dynamics)
    init_from_spec(model, spec, "inference", scene.name, scene.n_particles)
    stage = inference_stage(cfg.ablation)
    trainer, last = fit(cfg, stage, spec, model, dm)
    validate_final(trainer, model, dm)  # every rank: under DDP validation is collective; val/* below are last.ckpt's
    if not trainer.is_global_zero:  # under DDP rank 0 alone evaluates and writes
        return {"env": scene.name, "stage": stage, "checkpoint": str(last)}
    result = {"env": scene.name, "stage": stage, "checkpoint": str(last), **source, **stopping(trainer),
              **{k: float(v) for k, v in trainer.callback_metrics.items() if k.startswith("val/")}}
    out = Path(cfg.paths.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "metrics.json").write_text(json.dumps(result, indent=1))
    log.info("inference module: %s", result)
    return result
