"""An InferenceModule from the options a test varies, named flat (``training_scheme="joint"``,
``width=16``, ``tail_horizon=2``), composed into the parts the config composes: each part as the
config dict Hydra would pass, so the module builds them as train_inference's does."""

from __future__ import annotations

from vgpl.models.inference import InferenceModule

ENCODER = ("width", "propagation_steps", "max_neighbors", "separate_param_net", "param_rotation")
TRAINING = ("one_step_windows", "refined_steps", "truth_steps", "tail_horizon", "tail_detach_rigidness", "proposal_noise")


def parts(training_scheme: str = "paper", trajectory_start: str = "refined", rollout_target: str = "truth", refine_weight: float = 1.0,
          param_weight: float = 0.0, rigid_fit_start: bool = False, rigidness_estimator: str = "blend", lr: float = 1e-4, **options) -> dict:
    """The module's keyword arguments but the scene: encoder, training, scheme, target, rigidness_estimator, optimizer (and any left)."""
    scheme = ({"_target_": "vgpl.models.training_scheme.JointScheme", "start": trajectory_start} if training_scheme == "joint"
              else {"_target_": "vgpl.models.training_scheme.PaperScheme"})
    if rollout_target == "proposals":
        if refine_weight or param_weight:
            raise ValueError("the proposals target has no refinement or parameter weight")
        target = {"_target_": "vgpl.models.rollout_target.ProposalsTarget", "rigid_fit_start": rigid_fit_start}
    else:
        assert not rigid_fit_start, "rigid_fit_start is the proposals target's"
        target = {"_target_": "vgpl.models.rollout_target.TruthTarget", "refine_weight": refine_weight, "param_weight": param_weight}
    estimator = {"_target_": f"vgpl.models.rigidness_estimator.{'Bernoulli' if rigidness_estimator == 'bernoulli' else 'Blend'}Rigidness"}
    return {"encoder": {k: options.pop(k) for k in ENCODER if k in options}, "training": {k: options.pop(k) for k in TRAINING if k in options},
            "scheme": scheme, "target": target, "rigidness_estimator": estimator,
            "optimizer": {"_target_": "torch.optim.Adam", "_partial_": True, "lr": lr}, **options}


def inference_module(param_low, param_high, n_particles: int, n_instances: int, radius: float, instance_types=None, **options) -> InferenceModule:
    scene = {"param_low": list(param_low), "param_high": list(param_high), "n_particles": n_particles, "n_instances": n_instances,
             "radius": radius, "instance_types": instance_types}
    return InferenceModule(scene, **parts(**options))
