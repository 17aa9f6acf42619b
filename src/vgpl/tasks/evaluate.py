"""task=evaluate: the paper's evaluation of one method / ablation on one environment's test
videos, from checkpoint paths alone. Writes metrics.json (with ``breakdown@<n_steps>``: where the
last predicted frame's error comes from, binned by the true and by the inferred parameters),
params.csv (per test video: true and inferred parameters, future MSE at T+n_steps), with
``eval.error_sources=true`` error_sources.csv (the future error with each inferred input replaced
by the truth in turn),
table1/table2 (Markdown + CSV), PNG figures and TensorBoard events into the run folder;
task=report gathers many of them."""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import asdict
from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf
from torch.utils.tensorboard import SummaryWriter

from vgpl.checkpoint import load_stage, scene_of
from vgpl.data.inference_windows import proposals_path
from vgpl.data.proposals import exported_proposals, proposal_source
from vgpl.data.trajectories import load_split
from vgpl.data.window_pool import check_window_pool
from vgpl.eval import figures
from vgpl.eval.compare import PER_VIDEO_PARAM, PER_VIDEO_RIGIDNESS
from vgpl.eval.error_breakdown import error_breakdown, rollout_mse_x1e4
from vgpl.eval.error_sources import error_sources_rows
from vgpl.eval.paired import per_video_map
from vgpl.eval.preview import write_gif
from vgpl.eval.protocol import evaluate_grounding, proposed_frames
from vgpl.eval.tables import HORIZONS, PER_VIDEO, csv_text, markdown, param_rows, write_tables
from vgpl.eval.tensorboard_media import add_gif, rollout_video
from vgpl.eval.test_time_fit import TestTimeFit
from vgpl.models.dynamics_prior import DynamicsPrior
from vgpl.models.inference import InferenceModule
from vgpl.models.rollout import FUTURE
from vgpl.models.visual_prior import VisualPrior
from vgpl.tasks.stage import setup_run, stage_checkpoint
from vgpl.tasks.train_inference import ablation_prior, inference_stage

log = logging.getLogger(__name__)


def inference_checkpoint(cfg: DictConfig) -> Path:
    """``ckpt.inference`` (the full module, which no_refinement and no_params switch at evaluation
    time), or ``ckpt.inference_no_rigidness`` under ablation=no_rigidness (its own module); unset,
    the stage's last.ckpt under paths.ckpt_dir."""
    return stage_checkpoint(cfg, inference_stage(cfg.ablation))


def warn_other_prior(inference_path: Path, inference_cfg: DictConfig, dynamics_path: Path) -> str | None:
    """The warning (also logged) when the inference module at ``inference_path`` was trained through
    another dynamics prior than ``dynamics_path``: its P is fitted to that prior's rollout, and
    reads P off through another; None when they
    agree or its config does not say."""
    trained = stage_checkpoint(inference_cfg, ablation_prior(inference_cfg.get("ablation") or {})) if inference_cfg.get("paths") else None
    if trained is None or Path(trained).resolve() == Path(dynamics_path).resolve():
        return None
    message = (f"{inference_path}: trained through the dynamics prior {trained}, evaluated through {dynamics_path}; "
               "pass ckpt.dynamics=<its prior> unless the swap is the experiment")
    log.warning(message)
    return message


def evaluate(cfg: DictConfig) -> dict:
    setup_run(cfg)
    if cfg.model.name == "densephysnet":
        from vgpl.tasks.baseline import evaluate_baseline

        return evaluate_baseline(cfg)
    if cfg.model.name != "vgpl":
        raise ValueError(f"model.name='{cfg.model.name}': expected vgpl or densephysnet")
    fit = TestTimeFit(**(cfg.eval.get("test_time_fit") or {}))  # refused by its key before anything is loaded
    source, noise_std = proposal_source(cfg.eval.get("proposals", "visual"), cfg.eval.get("proposals_noise_std", 0.0),
                                        "eval.proposals", "eval.proposals_noise_std", exported=True)
    scene = scene_of(cfg)
    env, n = scene.name, scene.n_particles
    by_video = source == "visual"
    paths = {"dynamics": stage_checkpoint(cfg, ablation_prior(cfg.ablation)), "visual": stage_checkpoint(cfg, "visual") if by_video else None,
             "proposals": proposals_path(cfg.data.root, env, "test") if source == "exported" else None, "inference": inference_checkpoint(cfg)}
    dynamics, _ = load_stage(paths["dynamics"], DynamicsPrior, env=env, n_particles=n)
    visual = load_stage(paths["visual"], VisualPrior, env=env, n_particles=n)[0] if by_video else None
    inference, inference_cfg = load_stage(paths["inference"], InferenceModule, env=env, n_particles=n)
    warn_other_prior(paths["inference"], inference_cfg, paths["dynamics"])
    window_pool = trained_window_pool(cfg, inference_cfg)
    test = load_split(cfg.data.root, env, "test", images=by_video, max_rollouts=cfg.eval.get("max_rollouts"))
    if test.positions.shape[2] != n:
        raise ValueError(f"{cfg.data.root}/{env}/test: {test.positions.shape[2]} particles, the checkpoints expect {n}")
    observed = cfg.model.inference.observed if cfg.eval.get("observed") is None else cfg.eval.observed
    prop = None if paths["proposals"] is None else exported_test_proposals(cfg, paths["proposals"], test, observed, window_pool, n)
    exported = None if prop is None else (prop.positions, prop.logits, prop.slots)
    measured_on = curve_fingerprint(cfg, paths, source, noise_std, int(test.positions.shape[0]), observed, window_pool) if cfg.ablation.rigidness else None
    reused = cfg.eval.get("rigidness_curve_from") if cfg.ablation.rigidness else None
    result = evaluate_grounding(dynamics, visual, inference, scene, test, cfg.ablation, observed, cfg.eval.n_steps,
                                cfg.eval.get("max_observed", 20), cfg.env.get("start_frame", 0), cfg.seed,
                                curve_rollouts=cfg.eval.get("curve_rollouts"), truth_noise_std=noise_std,
                                rigidness_curve=None if reused is None else reused_rigidness_curve(reused, measured_on),
                                trace_sources=bool(cfg.eval.get("error_sources", False)), exported=exported,
                                progress=bool(cfg.data.get("progress", True)), window_pool=window_pool, test_time_fit=fit)
    record = {"env": env, "method": "vgpl", "ablation": cfg.ablation.name, **({"test_time_fit": asdict(fit)} if fit.steps else {}),
              "n_test": int(test.positions.shape[0]),
              "observed": observed, "proposals": source, "proposals_noise_std": noise_std, "window_pool": window_pool,
              "checkpoints": {k: str(v) for k, v in paths.items() if v is not None}, **result.metrics, "rigidness_curve": result.rigidness_curve}
    if result.rigidness_curve:
        record["rigidness_curve_measured_on"] = measured_on
        record["rigidness_curve_from"] = reused  # None: measured by this evaluation
    if result.sources:
        record["error_sources"] = result.sources
    names = list(scene.param_names)
    errors = add_per_video(record, result, test, scene, observed, cfg.eval.n_steps)
    out = Path(cfg.paths.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "metrics.json").write_text(json.dumps(record, indent=1))
    (out / "params.csv").write_text(csv_text(*param_rows(names, test.params, result.params, test.rollout_ids, {FUTURE.format(k): e for k, e in errors.items()})))
    text = write_tables([record], out, report_notes(out, source, noise_std, paths["proposals"], prop, result.sources))
    _figures_and_tensorboard(cfg, scene, test, result, observed, out)
    log.info("evaluation of %s (%s) on %s:\n%s", record["method"], record["ablation"], env, text)
    return record


def report_notes(out: Path, source: str, noise_std: float, proposals_path, prop, sources: dict) -> str:
    """The notes under the evaluation's tables: where the proposals came from unless the visual prior made them,
    and the error sources' table (also written to ``out``/error_sources.csv)."""
    notes = ""
    if source == "truth":
        notes += f"\nProposals: the recorded particles + N(0, {noise_std:g}^2) m (eval.proposals=truth), not the visual prior: a diagnostic.\n"
    if prop is not None:
        notes += f"\nProposals: the visual prior's, read from {proposals_path} (eval.proposals=exported; visual checkpoint {prop.attrs.get('visual_checkpoint')}).\n"
    if sources:
        header, rows = error_sources_rows(sources)
        (out / "error_sources.csv").write_text(csv_text(header, rows))
        notes += ("\n## Where the future error comes from (eval.error_sources)\n\nThe same prior rolled from the inferred inputs "
                  "with some taken from the recorded truth; future MSE x 1e4.\n\n" + markdown(header, rows) + "\n")
    return notes


def exported_test_proposals(cfg: DictConfig, path: Path, test, observed: int, window_pool: str, n_particles: int):
    """The test videos' proposals as task=export_proposals wrote them to ``path``, for the frames the evaluation reads."""
    start = cfg.env.get("start_frame", 0)
    frames = start + proposed_frames(observed, cfg.eval.get("max_observed", 20), test.positions.shape[1], start)
    prop = exported_proposals(path, test.rollout_ids, frames, window_pool)
    if prop.positions.shape[2] != n_particles:
        raise ValueError(f"{path}: proposals of {prop.positions.shape[2]} particles, the checkpoints expect {n_particles}")
    return prop


def add_per_video(record: dict, result, test, scene, observed: int, last: int) -> dict[int, torch.Tensor]:
    """Add to ``record`` the breakdown of the T+``last`` error by video and by what was inferred for it, and each
    video's parameter error, rigidness reading and future error (paired by task=compare). Returns T+k -> [R]
    the future error at Table 2's horizons and ``last``, for params.csv."""
    names = list(scene.param_names)
    record[f"breakdown@{last}"] = error_breakdown(result.prediction, result.truth, torch.as_tensor(scene.instance), torch.cat([test.params, result.params], 1),
                                                  last, names + [f"inferred_{n}" for n in names])
    record[PER_VIDEO_PARAM] = per_video_map(test.rollout_ids, result.param_error)
    for name, values in result.rigidness_correct.items():
        record[PER_VIDEO_RIGIDNESS.format(observed, name)] = per_video_map(test.rollout_ids, values)
    errors = {}
    for step in sorted({k for k in HORIZONS if k <= last} | {last}):
        errors[step] = rollout_mse_x1e4(result.prediction, result.truth, step)
        record[PER_VIDEO.format(step)] = per_video_map(test.rollout_ids, errors[step])
    return errors


def trained_window_pool(cfg: DictConfig, inference_cfg: DictConfig) -> str:
    """How the evaluation reads each observed window from the visual prior's windows: ``eval.window_pool``
    where set, else the pool the inference module was trained on (its checkpoint's config; 'last', the
    paper's, for modules trained before the option)."""
    trained = OmegaConf.select(inference_cfg, "model.inference.window_pool", default="last")
    return check_window_pool(cfg.eval.get("window_pool") or trained, "eval.window_pool")


def curve_fingerprint(cfg: DictConfig, paths: dict, source: str, noise_std: float, n_test: int, observed: int, window_pool: str = "last") -> dict:
    """What the rigidness curve depends on: the visual and inference checkpoints' contents (sha256),
    the proposals, the test videos, the curve's videos and lengths, and the seed where it draws the
    proposals' noise."""
    digests = {k: hashlib.sha256(Path(v).read_bytes()).hexdigest() for k, v in paths.items() if k != "dynamics" and v is not None}
    return {"env": cfg.env.name, "data_root": str(cfg.data.root), "n_test": n_test, "start_frame": int(cfg.env.get("start_frame", 0)),
            "observed": observed, "max_observed": cfg.eval.get("max_observed", 20), "curve_rollouts": cfg.eval.get("curve_rollouts"),
            "proposals": source, "proposals_noise_std": noise_std, "window_pool": window_pool, "sha256": digests,
            "seed": cfg.seed if source == "truth" and noise_std > 0 else None}  # the seed draws only the noise of truth proposals


def reused_rigidness_curve(path: str | Path, measured_on: dict) -> dict:
    """The rigidness curve of an earlier evaluation (its metrics.json, ``eval.rigidness_curve_from``)
    of the same inference checkpoint on the same proposals: ablations that infer rigidness share
    it, so the pipeline measures it once. Raises naming the file and the first thing that differs."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"eval.rigidness_curve_from={path}: no such file; expected the metrics.json of an evaluation that measured the curve")
    record = json.loads(path.read_text())
    then = record.get("rigidness_curve_measured_on")
    if not record.get("rigidness_curve") or then is None:
        raise ValueError(f"eval.rigidness_curve_from={path}: holds no rigidness curve with what it was measured on")
    for key, now in measured_on.items():
        if then.get(key) != now:
            raise ValueError(f"eval.rigidness_curve_from={path}: its curve was measured with {key}={then.get(key)!r}, this evaluation has {now!r}")
    return record["rigidness_curve"]


def _figures_and_tensorboard(cfg, scene, test, result, observed: int, out: Path) -> None:
    writer = SummaryWriter(str(out / "tensorboard"))
    tag = f"{scene.name}/{cfg.ablation.name}"
    for key, value in result.metrics.items():
        writer.add_scalar(f"eval/{key}", value, 0)
    steps = [k for k in (1, cfg.eval.n_steps) if k <= result.truth.shape[1]]
    figs = {
        "particles": figures.particles_figure(scene.camera, scene.instance, result.truth[0], result.prediction[0], steps, f"{tag}: test video 0"),
        "params": figures.params_figure(test.params[:, 0], result.params[:, 0], float(scene.param_low[0]), float(scene.param_high[0]), scene.param_names[0], tag),
    }
    if result.rigidness_curve:
        figs["rigidness"] = figures.rigidness_figure(result.rigidness_curve, observed, tag)
    for name, fig in figs.items():
        writer.add_figure(f"eval/{name}", fig, 0, close=False)
        figures.save(fig, out / f"{name}.png")
    video = rollout_video(scene.camera, scene.instance, result.truth[0], result.prediction[0])
    add_gif(writer, "eval/rollout_truth_vs_prediction", video, 0)
    write_gif(video, out / "rollout_truth_vs_prediction.gif", fps=15)
    writer.close()


def load_records(folder: str | Path) -> list[dict]:
    """Every evaluation record (metrics.json with a method) under ``folder``, e.g. a multirun folder."""
    records = []
    for path in sorted(Path(folder).rglob("metrics.json")):
        record = json.loads(path.read_text())
        if "method" in record and "env" in record:
            records.append(record)
    return records


def report(cfg: DictConfig) -> dict:
    """task=report task.dir=<folder>: one Table 1 and Table 2 from every evaluation under it (a
    multirun folder), or under each of a list of folders (``task.dir='[outputs/a,outputs/b]'``)."""
    folders = cfg.task.get("dir")
    folders = [folders] if folders is None or isinstance(folders, str) else list(folders)
    records = []
    for folder in folders:
        if folder in (None, "???") or not Path(folder).is_dir():
            raise ValueError(f"task.dir={folder!r}: expected the folder of a task=evaluate (multi)run, or a list of them")
        found = load_records(folder)
        if not found:
            raise ValueError(f"task.dir={folder}: no evaluation metrics.json under it (run task=evaluate first)")
        records += found
    out = Path(cfg.paths.output_dir)
    text = write_tables(records, out)
    print(text)
    return {"n_records": len(records), "report": str(out / "report.md")}  # the records are in report.md; printed whole they would bury it


