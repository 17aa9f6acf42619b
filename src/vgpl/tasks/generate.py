"""task=generate: simulate and render an environment into sharded HDF5 files.

Rollout g (0 <= g < n_rollouts) always gets the seed stream SeedSequence(seed, spawn_key=(g,)),
whatever the sharding, so shards never repeat a rollout and any worker can make any shard.
Rollouts [0, n_train) form the train split, the rest the test split. A shard that already exists
with the same configuration is skipped (resume); ``data.worker`` / ``data.num_workers`` split the
shards between processes or Hydra multirun jobs. A run of another configuration into the same
folder is refused, also while the first is running (vgpl.data.dataset_claim).
"""

from __future__ import annotations

import errno
import hashlib
import json
import logging
import math
import shutil
import tempfile
import time
from concurrent.futures import as_completed
from dataclasses import dataclass
from pathlib import Path

import hydra
import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from tqdm import tqdm

from vgpl.data.dataset_claim import DatasetClaim
from vgpl.data.shard import Shard, shard_is_complete, write_shard
from vgpl.sim.scene import Scene
from vgpl.workers import worker_pool

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ShardPlan:
    split: str
    index: int  # within the split
    rollouts: tuple[int, ...]  # global rollout ids

    def path(self, root: Path) -> Path:
        return root / self.split / f"shard_{self.index:05d}.h5"


def plan_shards(n_rollouts: int, train_fraction: float, shard_size: int) -> list[ShardPlan]:
    """Split rollouts 0..n_rollouts-1 into train/test and each split into shards of ``shard_size``.
    Bad values are refused by their key before anything is simulated: non-numbers, sizes below 1,
    and sizes that leave the test split empty while ``train_fraction`` < 1 asks for one."""
    for key, value, kind in (("n_rollouts", n_rollouts, int), ("shard_size", shard_size, int), ("train_fraction", train_fraction, (int, float))):
        if isinstance(value, bool) or not isinstance(value, kind):
            raise ValueError(f"data.{key}={value!r}: expected {'an integer' if kind is int else 'a number'}")
    if n_rollouts < 1:
        raise ValueError(f"data.n_rollouts must be >= 1, got {n_rollouts}")
    if not 0.0 < train_fraction <= 1.0:
        raise ValueError(f"data.train_fraction must be in (0, 1], got {train_fraction}")
    if shard_size < 1:
        raise ValueError(f"data.shard_size must be >= 1, got {shard_size}")
    n_train = min(n_rollouts, max(1, round(n_rollouts * train_fraction)))
    if train_fraction < 1.0 and n_train == n_rollouts:
        raise ValueError(f"data.n_rollouts={n_rollouts} with data.train_fraction={train_fraction} leaves the test split empty "
                         f"(round({n_rollouts} x {train_fraction}) = {n_train} train rollouts): use at least "
                         f"{math.ceil(1.5 / (1.0 - train_fraction))} rollouts, a smaller train_fraction, or train_fraction=1.0 for no test split")
    plans = []
    for split, ids in (("train", range(0, n_train)), ("test", range(n_train, n_rollouts))):
        for k, start in enumerate(range(0, len(ids), shard_size)):
            plans.append(ShardPlan(split, k, tuple(ids[start : start + shard_size])))
    return plans


def check_generate_options(cfg: DictConfig) -> None:
    """Refuse, by key, a generation option of the wrong type or sign before anything is claimed
    or written: the seed and the data sizes must be integers (sizes >= 1, ``data.worker`` >= 0),
    ``data.render`` and ``data.progress`` booleans."""
    data = cfg.data
    integers = {"seed": (cfg.seed, 0), "data.batch_size": (data.batch_size, 1), "data.processes": (data.processes, 1),
                "data.num_workers": (data.num_workers, 1), "data.worker": (data.worker, 0),
                "data.compression_level": (data.compression_level, 0)}
    for key, (value, low) in integers.items():
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{key}={value!r}: expected an integer")
        if value < low:
            raise ValueError(f"{key}={value}: expected an integer >= {low}")
    for key in ("render", "progress"):
        if not isinstance(data[key], bool):
            raise ValueError(f"data.{key}={data[key]!r}: expected true or false")


def check_writable(folder: Path) -> None:
    """Fail before any simulation when ``folder`` (data.root/<env>) cannot be created or written."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".write_check_"):
            pass
    except OSError as e:
        raise PermissionError(f"{folder}: cannot write the dataset there (data.root): {e.strerror or e}; nothing was simulated") from e


IMAGE_COMPRESSION_BOUND = 10.0  # gzip shrinks the rendered frames by less than this (they are mostly background)


def smallest_size(scene: Scene, n_rollouts: int, render: bool) -> int:
    """A lower bound on the bytes ``n_rollouts`` rollouts of ``scene`` take on disk: positions and
    velocities (float32, stored uncompressed), actions and parameters, and with ``render`` the
    frames at IMAGE_COMPRESSION_BOUND times smaller than raw."""
    t, n = scene.n_steps, scene.n_particles
    arrays = 4 * t * (2 * 3 * n + scene.action_dim) + 4 * len(scene.param_names) + 8
    frames = t * scene.camera.height * scene.camera.width * 3 / IMAGE_COMPRESSION_BOUND if render else 0
    return int(n_rollouts * (arrays + frames))


def check_space(folder: Path, needed: int) -> None:
    """Refuse, before any simulation, a dataset whose smallest size exceeds the free space of ``folder``."""
    free = shutil.disk_usage(folder).free
    if needed > free:
        raise OSError(errno.ENOSPC, f"{folder}: this dataset takes at least {human_bytes(needed)} (data.n_rollouts, data.render), "
                                    f"the disk has {human_bytes(free)} free; lower data.n_rollouts, pass data.render=false, or "
                                    "choose another data.root; nothing was simulated")


def human_bytes(n: float) -> str:
    for unit in ("B", "KB", "MB", "GB", "TB"):
        if n < 1000 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} TB"


def rollout_rng(seed: int, rollout: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(rollout,)))


def simulate_shard(scene: Scene, plan: ShardPlan, seed: int, batch_size: int, render: bool, device: str, progress=None) -> Shard:
    """Simulate (and render) the rollouts of one shard, ``batch_size`` scenes at a time."""
    renderer = scene.renderer() if render else None
    parts = []
    for start in range(0, len(plan.rollouts), batch_size):
        ids = plan.rollouts[start : start + batch_size]
        traj = scene.simulate([scene.sample(rollout_rng(seed, g)) for g in ids], device=device)
        images = None
        if renderer is not None:
            b, t, n, _ = traj.positions.shape
            images = renderer.render(traj.positions.reshape(b * t, n, 3)).reshape(b, t, *renderer.background.shape[:2], 3).cpu().numpy()
        parts.append((traj, images))
        if progress is not None:
            progress.update(len(ids))
    cat = lambda key: torch.cat([getattr(tr, key) for tr, _ in parts]).cpu().numpy().astype(np.float32)  # noqa: E731
    return Shard(
        positions=cat("positions"),
        velocities=cat("velocities"),
        instance=scene.instance.astype(np.int64),
        rigid=scene.rigid.astype(bool),
        params=cat("params"),
        actions=cat("actions"),
        rollout_ids=np.asarray(plan.rollouts, dtype=np.int64),
        images=np.concatenate([im for _, im in parts]) if render else None,
        attrs={},
    )


def scene_attrs(scene: Scene, seed: int) -> dict:
    return {
        "env": scene.name,
        "dt": scene.dt,
        "n_particles": scene.n_particles,
        "n_instances": scene.n_instances,
        "param_names": list(scene.param_names),
        "param_low": scene.param_low.astype(np.float32),
        "param_high": scene.param_high.astype(np.float32),
        "camera": scene.camera.to_json(),
        "seed": seed,
    }


def config_hash(env_cfg: DictConfig, data_cfg: DictConfig, seed: int) -> str:
    """Hash of everything that determines a shard's bytes: the env's name and scene (engine and
    renderer), the data's sizes and the seed; not worker assignment or batch size, nor the env's
    keys for the learned stages (graph_radius, rigid_head, the standard preset's budgets, ...),
    which change with the models without changing one byte of the data."""
    keep = {k: data_cfg[k] for k in ("n_rollouts", "train_fraction", "shard_size", "render")}
    env = {"name": env_cfg.name, "scene": OmegaConf.to_container(env_cfg.scene, resolve=True)}
    blob = json.dumps({"env": env, "data": keep, "seed": seed}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def dataset_claim(cfg: DictConfig, env: str, digest: str) -> DatasetClaim:
    """The claim of this run's configuration on ``data.root/<env>``."""
    data = cfg.data
    scene = cfg.env.scene
    return DatasetClaim(Path(data.root) / env, digest, {"env": env, "seed": cfg.seed,
                                                        **{k: data[k] for k in ("n_rollouts", "train_fraction", "shard_size", "render")},
                                                        "param_low": [float(v) for v in scene.param_low], "param_high": [float(v) for v in scene.param_high]})


def make_shard(cfg: DictConfig, plan: ShardPlan, digest: str, threads: int, progress=None) -> ShardPlan:
    """Simulate, render and write one shard (also the body of a worker process); it is renamed
    into place only while the folder is still claimed by this configuration."""
    torch.set_num_threads(threads)
    scene: Scene = hydra.utils.instantiate(cfg.env.scene)
    data = cfg.data
    shard = simulate_shard(scene, plan, cfg.seed, data.batch_size, data.render, cfg.device, progress)
    shard.attrs = {**scene_attrs(scene, cfg.seed), "split": plan.split, "shard": plan.index, "config_hash": digest}
    write_shard(plan.path(Path(data.root) / scene.name), shard, data.compression_level, place=dataset_claim(cfg, scene.name, digest).place)
    return plan


def generate(cfg: DictConfig) -> dict:
    """Generate ``cfg.env`` into ``cfg.data.root/<env>/<split>/shard_*.h5``; returns a summary.

    ``data.processes`` > 1 makes the shards in that many worker processes of one torch thread
    each (on CPU, two single-threaded processes outrun one process with two threads).
    """
    data = cfg.data
    check_generate_options(cfg)
    if not 0 <= data.worker < data.num_workers:
        raise ValueError(f"data.worker must be in [0, data.num_workers={data.num_workers}), got {data.worker}")
    if data.processes < 1:
        raise ValueError(f"data.processes must be >= 1, got {data.processes}")
    plans = [p for k, p in enumerate(plan_shards(data.n_rollouts, data.train_fraction, data.shard_size)) if k % data.num_workers == data.worker]
    scene: Scene = hydra.utils.instantiate(cfg.env.scene)
    root = Path(data.root) / scene.name
    check_writable(root)
    digest = config_hash(cfg.env, data, cfg.seed)
    todo = dataset_claim(cfg, scene.name, digest).claim(lambda: [p for p in plans if not shard_is_complete(p.path(root), digest)])
    needed = smallest_size(scene, sum(len(p.rollouts) for p in todo), bool(data.render))
    check_space(root, needed)  # the shards left to write (a resume's finished ones take their space already)
    log.info("%s: %d shard(s) for this worker, %d already complete, writing %d (at least %s) under %s", scene.name, len(plans),
             len(plans) - len(todo), len(todo), human_bytes(needed), root)
    start = time.perf_counter()
    n_rollouts = sum(len(p.rollouts) for p in todo)
    with tqdm(total=n_rollouts, desc=f"generate {scene.name}", unit="rollout", disable=not data.progress) as bar:
        if data.processes == 1 or len(todo) <= 1:
            for plan in todo:
                make_shard(cfg, plan, digest, int(cfg.threads), bar)
        else:
            with worker_pool(data.processes) as pool:  # spawned, each ending with this process
                jobs = [pool.submit(make_shard, cfg, plan, digest, 1) for plan in todo]
                for job in as_completed(jobs):
                    bar.update(len(job.result().rollouts))
    seconds = time.perf_counter() - start
    return {
        "env": scene.name,
        "root": str(root),
        "shards": [str(p.path(root)) for p in plans],
        "written": len(todo),
        "skipped": len(plans) - len(todo),
        "rollouts_written": n_rollouts,
        "seconds": seconds,
    }
