"""experiment=paper is the paper's recipe: every value in docs/paper.md's recipe table, and every
departure in its departures table switched off, for each env."""

from __future__ import annotations

import re

import pytest
import yaml
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from tests.conftest import REPO

ENVS = ("rigid_fall", "fluid_cube", "mass_rope")
PAPER = (REPO / "docs" / "paper.md").read_text()
CONFIG_KEY = r"`((?:model|trainer|env|task)\.[\w.]+)`"  # a backticked config key in a departure's key cell


def table(name: str) -> list[dict[str, str]]:
    """The rows of the markdown table between ``<!-- name -->`` and ``<!-- /name -->`` in docs/paper.md."""
    body = re.search(rf"<!-- {name} -->\n(.*?)<!-- /{name} -->", PAPER, re.S)
    assert body, f"docs/paper.md has no table marked <!-- {name} -->"
    lines = [line.strip().strip("|").split("|") for line in body.group(1).strip().splitlines()]
    header = [c.strip() for c in lines[0]]
    return [dict(zip(header, (c.strip() for c in cells))) for cells in lines[2:]]


def value(cfg, key: str):
    """The resolved value of ``key`` in ``cfg`` (KeyError when the config has no such key)."""
    node = OmegaConf.select(cfg, key, throw_on_missing=True, default=KeyError)
    if node is KeyError:
        raise KeyError(key)
    return OmegaConf.to_container(node, resolve=True) if OmegaConf.is_config(node) else node


@pytest.fixture(scope="module")
def paper_configs() -> dict:
    with initialize_config_dir(config_dir=str(REPO / "conf"), version_base="1.3"):
        return {env: compose("config", overrides=[f"env={env}", "experiment=paper"]) for env in ENVS}


def test_the_tables_are_read_whole():
    recipe, departures = table("paper-recipe"), table("departures")
    assert len(recipe) >= 30 and len(departures) >= 15
    assert all(row["source"].startswith(("paper:", "code:", "paper and code:")) for row in recipe)
    assert all(re.search(CONFIG_KEY, row["key"]) for row in departures)


@pytest.mark.parametrize("env", ENVS)
def test_every_recipe_value_is_the_papers(paper_configs, env):
    cfg, checked = paper_configs[env], 0
    for row in table("paper-recipe"):
        if row["env"] not in ("all", env):
            continue
        key = row["key"].strip("`")
        assert value(cfg, key) == yaml.safe_load(row["value"]), f"experiment=paper env={env}: {key} is not the paper's ({row['source']})"
        checked += 1
    assert checked >= 30


@pytest.mark.parametrize("env", ENVS)
def test_every_departure_is_off_in_the_paper_preset(paper_configs, env):
    cfg = paper_configs[env]
    for row in table("departures"):
        for key in re.findall(CONFIG_KEY, row["key"]):
            try:
                got = value(cfg, key)
            except KeyError:  # a key of another env's scene
                assert key.startswith("env.scene."), f"{key} ({row['departure']}) is in no config"
                continue
            assert got == yaml.safe_load(row["paper value"]), f"experiment=paper env={env}: {key} = {got!r} keeps '{row['departure']}' on"


def test_each_departure_is_on_in_some_preset_or_default(monkeypatch):
    """A departure the table lists is a real one: some preset sets it (resolved as on a machine
    with bf16 units, where ``${fast_precision:bf16-mixed}`` is bf16)."""
    from vgpl import hardware

    monkeypatch.setattr(hardware, "bf16_emulated", lambda *args, **kwargs: False)
    with initialize_config_dir(config_dir=str(REPO / "conf"), version_base="1.3"):
        configs = [compose("config", overrides=[f"env={env}", f"experiment={preset}"]) for env in ENVS for preset in ("quick", "standard")]
    for row in table("departures"):
        key = re.findall(CONFIG_KEY, row["key"])[0]
        paper = yaml.safe_load(row["paper value"])
        seen = [value(cfg, key) for cfg in configs if OmegaConf.select(cfg, key, default=KeyError) is not KeyError]
        assert any(v != paper for v in seen), f"no preset departs in '{row['departure']}' ({key}): drop the row"
