"""experiment=paper's whole pipeline at tiny sizes, on the CPU: only sizes (frames, videos, batches,
steps), the accelerator and the module's neighbour cap are overridden, every other value is the
preset's, so the code paths the paper's recipe takes (its unconstrained prior for w/o rigidness, the
paper training scheme, the pooled rigid head, four frames of history) run here before anyone spends
GPU-days on them. The cap: a visual prior trained for 4 steps puts every particle in one spot, and
the module's uncapped radius graph of 192 collapsed particles takes minutes a step on a CPU."""

from __future__ import annotations

import json

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from tests.conftest import REPO
from vgpl.tasks.pipeline import pipeline

pytestmark = pytest.mark.slow

PAPER = ["experiment=paper", "env=rigid_fall"]
SIZES = {  # key -> tiny value: what a CPU minute affords; nothing here changes the recipe
    "env.scene.n_steps": 34,  # 10 observed + 20 predicted + the history
    "data.n_rollouts": 20, "data.shard_size": 10, "data.batch_size": 10, "data.progress": False,  # 18 training and 2 test videos
    "trainer.accelerator": "cpu", "trainer.limit_train_batches": 4, "trainer.limit_val_batches": 1, "trainer.max_epochs": 1,
    "trainer.enable_progress_bar": False,
    "model.visual.batch_size": 4, "model.visual.trainer.max_steps": 4,
    "model.inference.trainer.max_epochs": 1, "model.inference.net.encoder.max_neighbors": 16,
    "eval.max_observed": 12,
}


def compose_paper(tmp, sizes: dict) -> OmegaConf:
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        return compose("config", overrides=[*PAPER, f"paths.root_dir={tmp}", f"paths.output_dir={tmp}/run",
                                            *(f"{k}={json.dumps(v) if isinstance(v, bool) else v}" for k, v in sizes.items())])


def leaves(node, prefix: str = "") -> dict:
    """Every leaf of a resolved config as {dotted key: value}."""
    if isinstance(node, dict):
        return {k: v for key, child in node.items() for k, v in leaves(child, f"{prefix}{key}.").items()}
    return {prefix.rstrip("."): node}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("paper")
    cfg = compose_paper(tmp, SIZES)
    return tmp, cfg, pipeline(cfg)


def test_only_sizes_differ_from_the_preset(tmp_path):
    preset = leaves(OmegaConf.to_container(compose_paper(tmp_path, {}), resolve=True))
    tiny = leaves(OmegaConf.to_container(compose_paper(tmp_path, SIZES), resolve=True))
    changed = {k for k in preset.keys() | tiny.keys() if preset.get(k, KeyError) != tiny.get(k, KeyError)}
    assert changed <= set(SIZES), sorted(changed - set(SIZES))


def test_the_papers_pipeline_runs_end_to_end_with_its_own_ablations_and_stages(run):
    tmp, cfg, result = run
    assert [r["ablation"] for r in result["records"]] == ["full", "no_rigidness_unconstrained", "no_refinement", "no_params"]
    ckpt = tmp / "checkpoints/paper/rigid_fall"
    for stage in ("dynamics", "dynamics_unconstrained", "visual", "inference", "inference_no_rigidness_unconstrained"):
        assert (ckpt / stage / "last.ckpt").is_file(), stage
    report = (tmp / "run/report.md").read_text()
    assert "| range midpoint (constant guess) |" in report and report.count("\n| VGPL |") == 2  # Table 1 and Table 2
    for record in result["records"]:
        assert record["n_test"] == 2 and all(torch.isfinite(torch.tensor(record[f"future_mse_x1e4@{k}"])) for k in (1, 5, 10, 20))


def test_the_checkpoints_carry_the_papers_recipe(run):
    tmp, cfg, _ = run
    ckpt = tmp / "checkpoints/paper/rigid_fall"
    dynamics = torch.load(ckpt / "dynamics/last.ckpt", map_location="cpu", weights_only=False)["hyper_parameters"]
    assert (dynamics["history"], dynamics["width"], dynamics["rigid_head"], dynamics["lr"]) == (4, 150, "pooled", 1e-5)
    assert torch.load(ckpt / "dynamics_unconstrained/last.ckpt", map_location="cpu", weights_only=False)["hyper_parameters"]["rigid_head"] == "none"
    inference = torch.load(ckpt / "inference/last.ckpt", map_location="cpu", weights_only=False)["hyper_parameters"]
    assert inference["scheme"]["_target_"] == "vgpl.models.training_scheme.PaperScheme"
    assert (inference["encoder"]["width"], inference["training"]["truth_steps"], inference["training"]["refined_steps"]) == (150, 2, 0)
