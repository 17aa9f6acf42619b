"""What every training task shares: the stage's stable checkpoint folder, its saved config, the
Lightning Trainer (TensorBoard logger, ModelCheckpoint with last.ckpt) and resuming."""

from __future__ import annotations

import logging
from pathlib import Path

import lightning as L
import torch
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.loggers import TensorBoardLogger
from omegaconf import DictConfig, OmegaConf

from vgpl.hardware import precision_warning

log = logging.getLogger(__name__)


def stage_dir(cfg: DictConfig, stage: str) -> Path:
    """``<paths.ckpt_dir>/<stage>``: stable across runs, so ``ckpt_path=last`` and evaluation find it."""
    return Path(cfg.paths.ckpt_dir) / stage


def stage_checkpoint(cfg: DictConfig, stage: str) -> Path:
    """The checkpoint a later stage uses: ``cfg.ckpt.<stage>`` when set, else the stage's last.ckpt."""
    given = (cfg.get("ckpt") or {}).get(stage)
    return Path(given) if given else stage_dir(cfg, stage) / "last.ckpt"


def setup_run(cfg: DictConfig) -> None:
    L.seed_everything(cfg.seed, workers=True)
    torch.set_num_threads(int(cfg.threads))


def fit(cfg: DictConfig, stage: str, stage_cfg: DictConfig, model: L.LightningModule, datamodule: L.LightningDataModule,
        monitor: str = "val/loss") -> tuple[L.Trainer, Path]:
    """Train ``model`` into ``<ckpt_dir>/<stage>/`` (checkpoints, config.yaml, tensorboard/).

    ``ckpt_path=last`` resumes from that folder's last.ckpt (Lightning's own resolution);
    ``stage_cfg.trainer`` overrides the ``trainer`` group for this stage. Returns the trainer
    and the path of last.ckpt.
    """
    folder = stage_dir(cfg, stage)
    folder.mkdir(parents=True, exist_ok=True)
    saved = OmegaConf.to_container(cfg, resolve=True)
    saved["stage"] = stage
    saved["stage_class"] = f"{type(model).__module__}.{type(model).__name__}"
    OmegaConf.save(OmegaConf.create(saved), folder / "config.yaml")
    kwargs = {**OmegaConf.to_container(cfg.trainer, resolve=True), **OmegaConf.to_container(OmegaConf.create(stage_cfg.get("trainer") or {}), resolve=True)}
    trainer = L.Trainer(
        **kwargs,
        logger=TensorBoardLogger(str(folder), name="tensorboard", version=""),
        callbacks=[ModelCheckpoint(dirpath=folder, filename="best", monitor=monitor, save_last=True)],
        default_root_dir=str(folder),
    )
    warning = precision_warning(str(kwargs.get("precision")), str(kwargs.get("accelerator", "auto")), torch.cuda.is_available())
    if warning:
        log.warning(warning)
    ckpt_path = cfg.get("ckpt_path")
    if ckpt_path == "last" and not (folder / "last.ckpt").is_file():
        log.info("%s: no last.ckpt yet, starting from scratch", folder)
        ckpt_path = None
    trainer.fit(model, datamodule, ckpt_path=ckpt_path)
    trainer.save_checkpoint(folder / "last.ckpt")  # also when validation never ran (tiny runs)
    return trainer, folder / "last.ckpt"
