"""What every training task shares: the stage's stable checkpoint folder, its saved config, the
Lightning Trainer (TensorBoard logger, ModelCheckpoint with last.ckpt) and resuming."""

from __future__ import annotations

import logging
from pathlib import Path

import lightning as L
import torch
from lightning.pytorch.callbacks import Callback, ModelCheckpoint, Timer
from lightning.pytorch.loggers import TensorBoardLogger
from omegaconf import DictConfig, OmegaConf

from vgpl.atomic_write import atomic_path
from vgpl.checkpoint import check_resume
from vgpl.hardware import precision_warning
from vgpl.models.step_learning_rate import training_clock
from vgpl.tasks.stage_folder import hold_stage_folder
from vgpl.weight_averaging import ExponentialMovingAverage

log = logging.getLogger(__name__)


def stage_dir(cfg: DictConfig, stage: str) -> Path:
    """``<paths.ckpt_dir>/<stage>``: stable across runs, so ``ckpt_path=last`` and evaluation find it."""
    return Path(cfg.paths.ckpt_dir) / stage


def stage_checkpoint(cfg: DictConfig, stage: str) -> Path:
    """The checkpoint a later stage uses: ``cfg.ckpt.<stage>`` when set, else the stage's last.ckpt."""
    given = (cfg.get("ckpt") or {}).get(stage)
    return Path(given) if given else stage_dir(cfg, stage) / "last.ckpt"


def dynamics_stage(unconstrained: bool) -> str:
    """Checkpoint folder of a dynamics prior: ``dynamics``, or ``dynamics_unconstrained`` for the
    prior without rigid-body constraints (``model.dynamics.net.rigid_head=none``) that
    ``ablation=no_rigidness_unconstrained`` rolls."""
    return "dynamics_unconstrained" if unconstrained else "dynamics"


def setup_run(cfg: DictConfig) -> None:
    L.seed_everything(cfg.seed, workers=True)
    torch.set_num_threads(int(cfg.threads))


def trainer_kwargs(cfg: DictConfig, stage_cfg: DictConfig) -> dict:
    """The Trainer's arguments for a stage: the ``trainer`` group, overridden by ``stage_cfg.trainer``.

    The stage's trainer is resolved where it sits in ``cfg``, so that its interpolations reach the
    whole config (``${oc.select:...}`` of another group); a copy made with OmegaConf.create would
    resolve them against itself and fall back to the default."""
    stage_trainer = stage_cfg.get("trainer") or {}
    if isinstance(stage_trainer, DictConfig):
        stage_trainer = OmegaConf.to_container(stage_trainer, resolve=True)
    return {**OmegaConf.to_container(cfg.trainer, resolve=True), **stage_trainer}


def fit(cfg: DictConfig, stage: str, stage_cfg: DictConfig, model: L.LightningModule, datamodule: L.LightningDataModule,
        monitor: str = "val/loss") -> tuple[L.Trainer, Path]:
    """Train ``model`` into ``<ckpt_dir>/<stage>/`` (checkpoints, config.yaml, tensorboard/).

    ``ckpt_path=last`` resumes from that folder's last.ckpt (Lightning's own resolution);
    ``stage_cfg.trainer`` overrides the ``trainer`` group for this stage; ``stage_cfg.ema.decay``
    (when set) validates and saves an exponential moving average of the weights
    (vgpl.weight_averaging); ``stage_cfg.snapshot_every_n_steps`` (when set) keeps a
    ``step<N>.ckpt`` every N steps beside last.ckpt. The run holds the folder while it trains
    (vgpl.tasks.stage_folder): a second training of it is refused, and so is a new training over a
    trained last.ckpt unless ``overwrite=true``. Returns the trainer and the path of last.ckpt.
    """
    check_batch_size(stage, stage_cfg)
    check_step_counts(cfg, stage_cfg, trainer_kwargs(cfg, stage_cfg))
    folder = stage_dir(cfg, stage)
    ckpt_path = cfg.get("ckpt_path")
    if ckpt_path == "last":
        if (folder / "last.ckpt").is_file():
            ckpt_path = folder / "last.ckpt"
        else:
            log.info("%s: no last.ckpt yet, starting from scratch", folder)
            ckpt_path = None
    if ckpt_path is not None:
        check_resume(ckpt_path, model, OmegaConf.select(cfg, "env.name"))  # before the folder gets this run's config and logs
    overwrite = cfg.get("overwrite", False)
    if not isinstance(overwrite, bool):
        raise ValueError(f"overwrite={overwrite!r}: expected true or false")
    with hold_stage_folder(folder, resuming=ckpt_path is not None, overwrite=overwrite):
        return _fit(cfg, stage, stage_cfg, model, datamodule, monitor, folder, ckpt_path)


def _fit(cfg, stage, stage_cfg, model, datamodule, monitor, folder: Path, ckpt_path) -> tuple[L.Trainer, Path]:
    saved = OmegaConf.to_container(cfg, resolve=True)
    saved["stage"] = stage
    saved["stage_class"] = f"{type(model).__module__}.{type(model).__name__}"
    kwargs = trainer_kwargs(cfg, stage_cfg)
    callbacks = [SaveConfig(folder / "config.yaml", OmegaConf.create(saved)), *checkpointing(folder, monitor), LastValidation(),
                 SpentTimeWarning(max_time_key(cfg, stage_cfg)), FiniteLoss(stage)]
    if stage_cfg.get("snapshot_every_n_steps") is not None:
        callbacks.append(snapshots(folder, int(stage_cfg.snapshot_every_n_steps)))
    ema = stage_cfg.get("ema") or {}
    if ema.get("decay") is not None:
        callbacks.append(ExponentialMovingAverage(float(ema.decay), int(ema.get("start_step", 0))))
    trainer = L.Trainer(
        **kwargs,
        logger=TensorBoardLogger(str(folder), name="tensorboard", version=""),
        callbacks=callbacks,
        default_root_dir=str(folder),
    )
    warning = precision_warning(str(kwargs.get("precision")), str(kwargs.get("accelerator", "auto")), torch.cuda.is_available())
    if warning:
        log.warning(warning)
    trainer.fit(model, datamodule, ckpt_path=None if ckpt_path is None else str(ckpt_path))
    trainer.save_checkpoint(folder / "last.ckpt")  # also when validation never ran (tiny runs)
    ended = stopping(trainer)
    if ended["stopped_by"] == "max_time":
        log.warning("%s: trainer.max_time=%s stopped training after %d of %d steps; its results depend on this machine's speed",
                    stage, kwargs.get("max_time"), ended["steps"], ended["max_steps"])
    return trainer, folder / "last.ckpt"


class SaveConfig(Callback):
    """Writes the run's config to ``path`` when the run saves its first checkpoint, not before: a
    run that fails first (a bad trainer option, a crash in the first steps) leaves the config.yaml
    of the checkpoint already there, which later stages rebuild the env and model from."""

    def __init__(self, path: Path, config: DictConfig) -> None:
        self.path, self.config, self.written = path, config, False

    def on_save_checkpoint(self, trainer: L.Trainer, pl_module: L.LightningModule, checkpoint: dict) -> None:
        if not self.written and trainer.is_global_zero:
            with atomic_path(self.path) as tmp:
                OmegaConf.save(self.config, tmp)
            self.written = True


class SpentTimeWarning(Callback):
    """Warns at fit start when the run resumed from a checkpoint whose training time already reaches
    ``max_time`` (``key`` names the option in the message).

    Lightning's Timer restores the training time spent before ``on_fit_start``, so ``max_time``
    bounds the total over every resumed run, not the new one: a resume with ``max_time=00:00:12:00``
    after 60 min stops at once, 0 steps. That is also what a finished stage of a
    resumed pipeline does, hence a warning and not an error. The Timer's own numbers are read
    (``training_clock``), not the checkpoint a second time."""

    def __init__(self, key: str = "trainer.max_time") -> None:
        self.key = key

    def on_fit_start(self, trainer, pl_module) -> None:
        spent, limit = training_clock(trainer)
        warning = spent_time_warning(trainer.ckpt_path, spent, limit, self.key)
        if warning:
            log.warning(warning)


def spent_time_warning(checkpoint: str | Path | None, spent: float | None, limit: float | None,
                       key: str = "trainer.max_time") -> str | None:
    """The warning for a resume from ``checkpoint`` that has spent ``spent`` of ``limit`` training
    seconds, or None when it has time left (or there is no checkpoint or no clock)."""
    if checkpoint is None or spent is None or limit is None or spent < limit:
        return None
    return (f"{checkpoint}: holds {duration(spent)} of training already, at or past {key}={duration(limit)}, which counts "
            f"every run resumed from it (Lightning's Timer), so this run stops before its first step; to train for another "
            f"hour pass {key}={duration(spent + 3600)} (the time spent plus the new)")


def max_time_key(cfg: DictConfig, stage_cfg: DictConfig) -> str:
    """The option a stage's max_time comes from (``trainer_option``)."""
    return trainer_option(cfg, stage_cfg, "max_time")


def trainer_option(cfg: DictConfig, stage_cfg: DictConfig, option: str) -> str:
    """The key a stage's trainer ``option`` comes from: ``model.<name>.trainer.<option>`` when the
    stage sets its own, else the ``trainer`` group's ``trainer.<option>``."""
    if option in (stage_cfg.get("trainer") or {}):
        for name, node in (cfg.get("model") or {}).items():
            if node is stage_cfg:
                return f"model.{name}.trainer.{option}"
    return f"trainer.{option}"


def check_step_counts(cfg: DictConfig, stage_cfg: DictConfig, kwargs: dict) -> None:
    """Refuse a step or epoch count that is not a whole number, by its key (Lightning would run
    ``max_steps=3.5`` as 4 steps without a word): ``max_steps`` and ``max_epochs`` are integers,
    -1 for no limit, or null."""
    for option in ("max_steps", "max_epochs"):
        value = kwargs.get(option)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < -1):
            raise ValueError(f"{trainer_option(cfg, stage_cfg, option)}={value!r}: expected an integer >= 0, or -1 for no limit")


def duration(total_s: float) -> str:
    """Seconds as trainer.max_time's ``DD:HH:MM:SS``."""
    minutes, s = divmod(round(total_s), 60)
    hours, m = divmod(minutes, 60)
    days, h = divmod(hours, 24)
    return f"{days:02d}:{h:02d}:{m:02d}:{s:02d}"


def check_batch_size(stage: str, stage_cfg: DictConfig) -> None:
    """Refuse a ``model.<stage>.batch_size`` that is not a positive integer, by its config key (the
    DataLoader's own error names neither the stage nor the key, and comes after the data loaded)."""
    size = stage_cfg.get("batch_size")
    if size is not None and (isinstance(size, bool) or not isinstance(size, int) or size < 1):
        raise ValueError(f"model.{stage}.batch_size={size!r}: expected a positive integer")


def checkpointing(folder: str | Path, monitor: str) -> list[ModelCheckpoint]:
    """Keep ``<folder>/best.ckpt`` (lowest ``monitor``) and ``<folder>/last.ckpt`` (the latest
    validation), both overwritten in place.

    last.ckpt has its own unmonitored callback: Lightning's ``save_last`` writes it only at a
    validation that also saved a top-k checkpoint, so once ``monitor`` stopped improving a kill
    sent ``ckpt_path=last`` back to the last improvement. The version counter is off: when a run
    resumed from a checkpoint made in another folder (a copy, to train on) it wrote
    ``last-v1.ckpt`` and ``best-v1.ckpt`` beside the copy's files. After such a copy Lightning does
    not carry the best score over, so best.ckpt is the resumed run's best."""
    return [ModelCheckpoint(dirpath=folder, filename="best", monitor=monitor, enable_version_counter=False),
            ModelCheckpoint(dirpath=folder, filename="last", enable_version_counter=False)]


class FiniteLoss(Callback):
    """Stops a training whose loss is not finite, with one error naming the stage and the step,
    before a validation could save the weights it left (NaN in a shard, a diverging rate)."""

    def __init__(self, stage: str) -> None:
        self.stage = stage

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        loss = outputs["loss"] if isinstance(outputs, dict) else outputs
        if loss is not None and not bool(torch.isfinite(loss).all()):
            raise FloatingPointError(
                f"{self.stage}: the training loss is {float(loss)} at step {trainer.global_step}; stopped before any checkpoint could "
                "hold the weights it left. Check the data (task=generate validates shards; a NaN in a rollout is named there) or lower "
                "the learning rate; ckpt_path=last resumes from the last finite checkpoint")


class LastValidation(Callback):
    """Records ``step``, the global step of the latest validation (sanity checks excluded; None
    before the first), so that a task can tell whether ``trainer.callback_metrics`` describe the
    final weights (``validate_final``)."""

    def __init__(self) -> None:
        self.step: int | None = None

    def on_validation_end(self, trainer, pl_module) -> None:
        if not trainer.sanity_checking:
            self.step = trainer.global_step


def validate_final(trainer: L.Trainer, model: L.LightningModule, datamodule: L.LightningDataModule) -> None:
    """Validate the weights a fit ended with, unless its last validation was at its last step, so
    that ``trainer.callback_metrics`` describe last.ckpt (measured at ``trainer.global_step``).

    Why: validation runs every ``val_check_interval`` steps, so a fit of 1,822 steps validated at
    1,500 would report step 1,500's numbers beside "steps: 1822". The extra validation is
    logged to TensorBoard at the final step; it saves no checkpoint (fit already wrote last.ckpt)."""
    seen = next((c for c in trainer.callbacks if isinstance(c, LastValidation)), None)
    if seen is None or seen.step != trainer.global_step:
        trainer.validate(model, datamodule=datamodule, verbose=False)


def snapshots(folder: str | Path, every_n_steps: int) -> ModelCheckpoint:
    """Keeps ``<folder>/step<N>.ckpt`` every ``every_n_steps`` training steps, all of them (the
    course of a long run, to evaluate afterwards); with an EMA they hold the averaged weights, as
    last.ckpt, and ``trained_weights_checkpoint`` gives the trained ones."""
    if every_n_steps < 1:
        raise ValueError(f"snapshot_every_n_steps={every_n_steps}: expected a positive number of steps, or null for none")
    return ModelCheckpoint(dirpath=folder, filename="step{step}", every_n_train_steps=every_n_steps, save_top_k=-1,
                           auto_insert_metric_name=False, save_on_train_epoch_end=False)


def stopping(trainer: L.Trainer) -> dict:
    """How a fit ended: the steps run, the max_steps asked for, the limit that stopped it
    (``max_steps``, ``max_time`` or ``max_epochs``) and the precision it trained in (each stage
    has its own: the standard preset's prior in bf16, its visual prior in fp32). A fit cut by
    max_time ran fewer steps than asked, so its numbers depend on the machine's speed."""
    steps, max_steps = trainer.global_step, trainer.max_steps
    timer = next((c for c in trainer.callbacks if isinstance(c, Timer)), None)
    if 0 <= max_steps <= steps:
        by = "max_steps"
    elif timer is not None and timer.time_remaining() is not None and timer.time_remaining() <= 0.0:
        by = "max_time"
    else:
        by = "max_epochs"
    return {"steps": steps, "max_steps": max_steps, "stopped_by": by, "precision": str(trainer.precision)}
