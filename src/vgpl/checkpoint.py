"""Loading a trained stage from its checkpoint path alone, with one clear error when it does not fit.

Every training task writes ``<ckpt_dir>/<stage>/{last,best}.ckpt`` and the resolved run config
``config.yaml`` beside them; the config rebuilds the environment, so evaluation needs nothing else.
"""

from __future__ import annotations

import logging
import pickle
from collections.abc import Sequence
from pathlib import Path

import hydra
import torch
from omegaconf import DictConfig, OmegaConf

log = logging.getLogger(__name__)


class CheckpointError(ValueError):
    """A checkpoint is missing or does not match what it is used for."""


def load_stage(path: str | Path, cls, env: str | None = None, n_particles: int | None = None):
    """(module of class ``cls`` in eval mode on the CPU, its training config).

    Raises CheckpointError naming the file when it is missing, was trained for another stage, or
    for another environment / particle count than ``env`` / ``n_particles``.
    """
    path = Path(path)
    cfg = saved_config(path, cls, env)
    if n_particles is not None:
        have = scene_of(cfg).n_particles
        if have != n_particles:
            raise CheckpointError(f"{path}: trained for {have} particles, the data has {n_particles}")
    try:
        model = cls.load_from_checkpoint(str(path), map_location="cpu")
    except (RuntimeError, EOFError, KeyError, pickle.UnpicklingError) as error:  # torch's own messages do not name the file
        raise unreadable(path, cls, error) from error
    except TypeError as error:  # hyperparameters this code's constructor does not take
        raise CheckpointError(f"{path}: a {cls.__name__} checkpoint saved with constructor arguments this code's {cls.__name__} does not take "
                              f"(an older version; {error}); retrain it with this version") from error
    return model.eval(), cfg


def check_resume(path: str | Path, model, env: str | None) -> None:
    """The gate of a ``ckpt_path`` resume, run before the stage folder is touched: ``path`` must be
    a readable checkpoint of ``model``'s class, trained on ``env``, whose weights have
    ``model``'s names and shapes. Raises CheckpointError naming the file and what did not match
    (Lightning's own errors name neither, and come after the stage's config and logs are written)."""
    path = Path(path)
    saved_config(path, type(model), env, option="ckpt_path")
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)["state_dict"]
    except (RuntimeError, EOFError, KeyError, TypeError, pickle.UnpicklingError) as error:
        raise unreadable(path, type(model), error) from error
    own = model.state_dict()
    differ = differing_keys(own, state)
    if differ:
        raise CheckpointError(f"{path}: ckpt_path: a {type(model).__name__} checkpoint whose weights do not fit this run's {type(model).__name__} "
                              f"({listed(differ)}: another net config); resume with the config it was "
                              "trained with, or start from its weights with init_from")


def differing_keys(own: dict, state: dict) -> list[str]:
    """Keys of the state dict ``own`` missing from ``state`` or of another shape there, then the
    keys of ``state`` that ``own`` lacks."""
    return [k for k in own if k not in state or state[k].shape != own[k].shape] + [k for k in state if k not in own]


def listed(keys: list[str], most: int = 3) -> str:
    """The first ``most`` keys, comma-separated, with ', ...' when there are more."""
    return ", ".join(keys[:most]) + (", ..." if len(keys) > most else "")


def saved_config(path: Path, cls, env: str | None, option: str | None = None) -> DictConfig:
    """The training config saved beside the checkpoint ``path``, once the file exists, the config
    names ``cls`` as its stage's class and ``env`` (when given) as its env; CheckpointError
    naming the file (and ``option``, the key that passed it) otherwise."""
    given = f" ({option})" if option else ""
    if not path.is_file():
        raise CheckpointError(f"{path}{given}: no such checkpoint ({cls.__name__}); train it first, or pass its path")
    config_file = path.parent / "config.yaml"
    if not config_file.is_file():
        raise CheckpointError(f"{config_file}: missing beside {path.name}{given}; a vgpl training task saves its config there, "
                              "which rebuilds the environment (is this a checkpoint written by one?)")
    cfg = OmegaConf.load(config_file)
    saved_cls = cfg.get("stage_class")  # written by vgpl.tasks.stage.fit
    if saved_cls is not None and saved_cls != f"{cls.__module__}.{cls.__name__}":
        raise CheckpointError(f"{path}{given}: a {saved_cls} checkpoint, expected {cls.__module__}.{cls.__name__}")
    trained_env = OmegaConf.select(cfg, "env.name")
    if env is not None and trained_env is not None and trained_env != env:
        raise CheckpointError(f"{path}{given}: trained on env '{trained_env}', used for env '{env}' (pass env={trained_env} to use it)")
    return cfg


def unreadable(path: Path, cls, error: Exception) -> CheckpointError:
    """The CheckpointError for torch's failure ``error`` to load ``path`` as a ``cls`` checkpoint."""
    lines = str(error).splitlines() if isinstance(error, RuntimeError) else []  # an unpickling error's advice is torch's, not ours
    if lines and lines[0].startswith("Error(s) in loading state_dict"):  # read fine; its layers are not this code's
        mismatch = "; ".join(line.strip() for line in lines[1:4] if line.strip())
        return CheckpointError(f"{path}: a {cls.__name__} checkpoint whose weights do not fit this code's {cls.__name__} "
                               f"(saved with other layer names or shapes: another net config or version; {mismatch})")
    detail = f": {lines[0]}" if lines else ""
    return CheckpointError(f"{path}: not a readable {cls.__name__} checkpoint (truncated, or another file; {type(error).__name__}{detail})")


def init_weights(model, path: str | Path, spec_key: str, env: str, n_particles: int | None = None, reset: Sequence[str] = ()) -> None:
    """Start ``model`` from the weights (and buffers: normalisation statistics) of the checkpoint
    ``path`` of the same class, keeping ``model``'s own hyperparameters (e.g. its learning rate):
    a fine-tune with a fresh optimiser and timer, unlike ``ckpt_path`` which resumes a run.
    ``reset`` names submodules (e.g. ``rigid_head``) that keep ``model``'s fresh initialisation
    instead: a new head on a trained trunk. ``spec_key`` (e.g. ``model.inference``) is the stage's
    config group, whose ``init_from``, ``init_reset`` and ``net`` the errors name."""
    source, _ = load_stage(path, type(model), env=env, n_particles=n_particles)
    own = model.state_dict()
    under = lambda key, name: key == name or key.startswith(name + ".")  # noqa: E731
    fresh = lambda key: any(under(key, name) for name in reset)  # noqa: E731
    for name in reset:
        if not any(under(key, name) for key in own):
            raise CheckpointError(f"{spec_key}.init_reset: {name!r} is no submodule of {type(model).__name__}, expected one of {sorted({k.split('.')[0] for k in own})}")
    state = {k: v for k, v in source.state_dict().items() if not fresh(k)} | {k: v for k, v in own.items() if fresh(k)}
    differ = differing_keys(own, state)
    if differ:
        raise CheckpointError(f"{path}: {spec_key}.init_from has other layer shapes than {spec_key}.net ({listed(differ)}; "
                              f"{spec_key}.init_reset: [{differ[0].split('.')[0]}] would start that submodule fresh)")
    model.load_state_dict(state)
    log.info("%s initialised from %s%s", type(model).__name__, path, f", {', '.join(reset)} fresh" if reset else "")


def init_from_spec(model, spec: DictConfig, stage: str, env: str, n_particles: int | None = None) -> None:
    """``init_weights`` from a stage's config ``spec`` (``model.<stage>``: ``init_from``, ``init_reset``);
    nothing without ``init_from``, and an ``init_reset`` without it is refused rather than ignored."""
    reset = list(spec.get("init_reset") or ())
    if not spec.get("init_from"):
        if reset:
            raise ValueError(f"model.{stage}.init_reset={reset}: needs model.{stage}.init_from, the checkpoint whose other weights are kept")
        return
    init_weights(model, spec.init_from, f"model.{stage}", env, n_particles, reset)


def scene_of(cfg: DictConfig):
    """The Scene a (training) config describes."""
    return hydra.utils.instantiate(cfg.env.scene)
