"""docs/configuration.md has an entry for every config key: a key added without one fails here."""

from __future__ import annotations

import re

from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from tests.conftest import REPO

DOCUMENTED = set(re.findall(r"^\| `([\w.]+)` \|", (REPO / "docs" / "configuration.md").read_text(), re.M))


def leaf_keys(node, prefix: str = "") -> list[str]:
    """Dotted paths of every key of a config, the dicts' own keys included."""
    keys = []
    for key in node.keys():  # noqa: SIM118 (a ??? value is a key too)
        path = f"{prefix}{key}"
        keys.append(path)
        child = OmegaConf.select(node, str(key), throw_on_missing=False, throw_on_resolution_failure=False)
        if OmegaConf.is_dict(child) and not re.fullmatch(r"model\.\w+\.(trainer|ema)", path):  # a stage's trainer overrides and its EMA pair: one entry each
            keys += leaf_keys(child, f"{path}.")
    return keys


def documented(key: str) -> bool:
    """The key, or the dict it belongs to when that entry speaks for its members (env.scene.*, a part's class)."""
    if key.endswith(("._target_", "._partial_")) and key.rsplit(".", 1)[0] in DOCUMENTED:  # a part's class: its own entry names it
        return True
    return key in DOCUMENTED or any(key.startswith(f"{parent}.") for parent in ("env.scene", "hydra"))


PARTS = ("inference_scheme", "rollout_target", "rigidness_estimator")  # the inference module's part groups: each choice has its own keys


def every_config_key() -> set[str]:
    """The keys of the config composed for each env, each task and each choice of the part groups."""
    choices = [f"{group}={p.stem}" for group in PARTS for p in sorted((REPO / "conf" / group).glob("*.yaml"))]
    overrides = ([f"env={env}"] for env in ("rigid_fall", "fluid_cube", "mass_rope"))
    keys = set()
    with initialize_config_dir(config_dir=str(REPO / "conf"), version_base="1.3"):
        for chosen in [*overrides, *([f"task={p.stem}"] for p in sorted((REPO / "conf" / "task").glob("*.yaml"))), *([c] for c in choices)]:
            keys |= set(leaf_keys(compose("config", overrides=[*chosen, "experiment=none"])))
    return keys


def test_every_key_of_every_env_and_task_config_has_an_entry():
    missing = {k for k in every_config_key() if not documented(k)}
    assert not missing, f"config keys with no entry in docs/configuration.md: {sorted(missing)}"


def test_the_entries_name_only_keys_that_exist():
    keys = every_config_key()
    groups = {"experiment", "per_env"}  # the groups table's rows: chosen, not keys of the composed config
    stale = {k for k in DOCUMENTED - groups if k not in keys}
    assert not stale, f"docs/configuration.md documents keys no config has: {sorted(stale)}"
