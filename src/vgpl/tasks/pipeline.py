"""task=pipeline (the default of ``python run.py``): the whole of VGPL on one environment.

generate -> train_dynamics [-> train_dynamics_unconstrained, the prior without rigid-body
constraints, when ``task.ablations`` holds no_rigidness_unconstrained] -> identifiability (can the
prior's rollout loss find P? warn or stop) -> train_visual -> export_proposals -> train_inference
(full, and each w/o-rigidness variant asked for) -> [train_baseline] -> evaluate (every ablation [and the baseline]; the rigidness
curve is measured by the first ablation that infers rigidness and reused by the others, which
share its module) -> report.
Each step writes into ``<run dir>/<step>/`` (and ``pipeline.json``: each step's seconds, each
training's steps run); checkpoints go to the stable ``paths.ckpt_dir``,
so ``ckpt_path=last`` resumes a killed pipeline (finished shards are skipped, training resumes).
``task.time_budget.total`` (the quick preset's 9 min 30 s) shortens the trainings' max_time when
the untimed steps ran late (vgpl.tasks.time_budget).
"""

from __future__ import annotations

import gc
import json
import logging
import time
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from vgpl.eval.tables import write_tables
from vgpl.tasks.at_once import run_at_once, threads_each
from vgpl.tasks.evaluate import evaluate
from vgpl.tasks.generate import generate
from vgpl.tasks.identifiability import check_identifiability, identifiability_summary
from vgpl.tasks.stage import trainer_kwargs
from vgpl.tasks.time_budget import TimeBudget, seconds
from vgpl.tasks.train_dynamics import train_dynamics
from vgpl.tasks.train_inference import train_inference
from vgpl.tasks.train_visual import export_proposals, train_visual

log = logging.getLogger(__name__)

ABLATIONS = ("full", "no_rigidness", "no_rigidness_unconstrained", "no_refinement", "no_params")


def ablation_config(name: str) -> DictConfig:
    """The flags of conf/ablation/<name>.yaml (a test keeps the two in agreement)."""
    if name not in ABLATIONS:
        raise ValueError(f"ablation '{name}': expected one of {list(ABLATIONS)}")
    return OmegaConf.create({"name": name, "rigidness": not name.startswith("no_rigidness"), "refinement": name != "no_refinement",
                             "params": name != "no_params", "unconstrained_prior": name == "no_rigidness_unconstrained"})


def step_config(cfg: DictConfig, out: Path, step: str, **updates) -> DictConfig:
    """A resolved copy of ``cfg`` writing into ``out/step``, with top-level keys replaced."""
    c = OmegaConf.create(OmegaConf.to_container(cfg, resolve=True))
    c.paths.output_dir = str(out / step)
    for key, value in updates.items():
        c[key] = value
    return c


def modules_at_once(cfg: DictConfig, modules: list[str]) -> bool:
    """Whether the inference modules train side by side (``task.modules_at_once``): on a CPU with at
    least one thread for each; otherwise one after the other, as on an accelerator."""
    if not cfg.task.get("modules_at_once", False) or len(modules) < 2:
        return False
    if cfg.device != "cpu" or int(cfg.threads) < len(modules):
        log.info("task.modules_at_once: %d modules on device=%s with threads=%s train one after the other "
                 "(side by side needs a CPU and a thread for each)", len(modules), cfg.device, cfg.threads)
        return False
    return True


def module_config(c: DictConfig, threads: int, max_time: float | None) -> DictConfig:
    """A module's step config for training beside the others: ``threads`` torch threads, the
    pair's ``max_time`` (s; None: the stage's own) and no progress bar (the bars would interleave)."""
    c.threads = threads
    trainer = OmegaConf.to_container(c.model.inference.get("trainer") or OmegaConf.create({}))
    trainer["enable_progress_bar"] = False
    if max_time is not None:
        trainer["max_time"] = {"seconds": max_time}
    c.model.inference.trainer = trainer
    return c


def trainings(cfg: DictConfig) -> dict[str, str]:
    """The pipeline's training steps in the order it runs them -> the ``model.<stage>`` each trains."""
    steps = {"train_dynamics": "dynamics"}
    if "no_rigidness_unconstrained" in cfg.task.ablations:
        steps["train_dynamics_unconstrained"] = "dynamics"
    steps |= {"train_visual": "visual", "train_inference/full": "inference"}
    for name in ("no_rigidness", "no_rigidness_unconstrained"):
        if name in cfg.task.ablations:
            steps[f"train_inference/{name}"] = "inference"
    if cfg.task.get("baseline", False):
        steps["train_baseline"] = "densephysnet"
    return steps


def time_budget(cfg: DictConfig) -> TimeBudget:
    """``task.time_budget`` over the planned max_time of each of the pipeline's trainings (off for a
    task config without the block, as before it existed)."""
    planned = {step: seconds(trainer_kwargs(cfg, cfg.model[stage]).get("max_time"), f"model.{stage}.trainer.max_time")
               for step, stage in trainings(cfg).items()}
    spec = cfg.task.get("time_budget")
    if spec is None:
        return TimeBudget(None, planned)
    return TimeBudget(seconds(spec.total, "task.time_budget.total"), planned, reserve_s=spec.reserve_s, floor=spec.floor)


def pipeline(cfg: DictConfig) -> dict:
    out = Path(cfg.paths.output_dir)
    times: dict[str, float] = {}
    stages = trainings(cfg)
    budget = time_budget(cfg)

    def run(step: str, fn, **updates):
        start = time.perf_counter()
        log.info("pipeline: %s", step)
        c = step_config(cfg, out, step, **updates)
        if step in stages:  # a training: its max_time as the budget allows (its own, as the preset spells it, unless shortened)
            max_time = budget.max_time(step)
            if budget.shortened(step):
                stage = c.model[stages[step]]
                stage.trainer = {**(stage.get("trainer") or {}), "max_time": {"seconds": max_time}}
        result = fn(c)
        gc.collect()  # what a stage held (videos) can sit in reference cycles (trainer <-> module): free it before the next stage loads its own
        times[step] = round(time.perf_counter() - start, 1)
        return result

    trained: dict[str, dict] = {}  # step -> its training's end (steps, max_steps, stopped_by)
    run("generate", generate)
    trained["train_dynamics"] = run("train_dynamics", train_dynamics)
    if "train_dynamics_unconstrained" in stages:  # the prior VGPL w/o rigidness rolls in the paper: no rigid-body constraints
        free = OmegaConf.to_container(cfg.model, resolve=True)
        free["dynamics"]["net"]["rigid_head"] = "none"
        trained["train_dynamics_unconstrained"] = run("train_dynamics_unconstrained", train_dynamics, model=free)
    identifiability = run("identifiability", check_identifiability)
    trained["train_visual"] = run("train_visual", train_visual)
    run("export_proposals", export_proposals)
    modules = [step for step in stages if step.startswith("train_inference/")]  # full [and no_rigidness], in the budget's order
    together = modules if modules_at_once(cfg, modules) else []
    if together:
        start, each = time.perf_counter(), threads_each(int(cfg.threads), len(modules))
        max_time = budget.max_time_together(modules)
        configs = {step: module_config(step_config(cfg, out, step, ablation=ablation_config(step.removeprefix("train_inference/"))), each, max_time)
                   for step in modules}
        log.info("pipeline: %s side by side, %d thread(s) each", " and ".join(modules), each)
        trained |= run_at_once(train_inference, configs)
        times |= dict.fromkeys(modules, round(time.perf_counter() - start, 1))  # side by side: each step's time is the pair's
    else:
        for step in modules:
            trained[step] = run(step, train_inference, ablation=ablation_config(step.removeprefix("train_inference/")))
    baseline = "train_baseline" in stages
    if baseline:
        from vgpl.tasks.baseline import train_baseline

        trained["train_baseline"] = run("train_baseline", train_baseline)
    records = evaluate_all(cfg, out, run, baseline)
    notes = ("" if identifiability.get("skipped") else identifiability_summary(identifiability)) + training_summary(trained, times, budget.given, together)
    text = write_tables(records, out, notes)
    print(text)
    log.info("pipeline step times (s): %s", times)
    ends = {step: {k: r[k] for k in ("steps", "max_steps", "stopped_by", "precision")} | budget.given.get(step, {})
            for step, r in trained.items() if "steps" in r}
    (out / "pipeline.json").write_text(json.dumps({"env": cfg.env.name, "times_s": times, "trained": ends}, indent=1))
    return {"env": cfg.env.name, "identifiability": identifiability, "records": records, "times_s": times, "report": str(out / "report.md")}


def training_summary(trained: dict[str, dict], times: dict[str, float], given: dict[str, dict] | None = None,
                     together: list[str] = ()) -> str:
    """Markdown lines: each training step's steps run of those asked and its time, flagging those
    that trainer.max_time cut short (their numbers depend on the machine's speed), those whose
    max_time the pipeline's time budget shortened (``given``: TimeBudget.given) and those trained
    side by side (``together``: their time is the group's)."""
    lines = ["", "Training steps run (of max_steps) and wall time:", ""]
    for step, result in trained.items():
        if "steps" not in result:  # DDP ranks other than 0 return no metrics
            continue
        cut = " **stopped by trainer.max_time**" if result["stopped_by"] == "max_time" else ""
        g = (given or {}).get(step)
        if g and g["max_time_s"] < g["planned_s"]:
            cut += f" (task.time_budget shortened its max_time from {g['planned_s']:.0f} s to {g['max_time_s']:.0f} s)"
        beside = [other for other in together if other != step] if step in together else []
        at_once = f" side by side with {' and '.join(beside)}" if beside else ""
        lines.append(f"- {step}: {result['steps']} of {result['max_steps']} steps, {times.get(step, float('nan')):.0f} s{at_once}{cut}")
    return "\n".join(lines) + "\n"


def evaluate_all(cfg: DictConfig, out: Path, run, baseline: bool) -> list[dict]:
    """Every ablation's evaluation record, then DensePhysNet's with ``baseline``; ``run(step, task, **updates)``
    runs one step. The ablations that infer rigidness use one module: its rigidness curve is measured once."""
    records, curve_from = [], None
    for a in cfg.task.ablations:
        flags = ablation_config(a)
        shared = {**OmegaConf.to_container(cfg.eval, resolve=True), "rigidness_curve_from": curve_from if flags.rigidness else None}
        records.append(run(f"evaluate/{a}", evaluate, ablation=flags, eval=shared))
        if flags.rigidness and curve_from is None:
            curve_from = str(out / f"evaluate/{a}" / "metrics.json")
    if baseline:
        records.append(run("evaluate/densephysnet", evaluate, model={**OmegaConf.to_container(cfg.model, resolve=True), "name": "densephysnet"}))
    return records
