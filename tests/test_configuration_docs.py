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
    """The key, or the dict it belongs to when that entry speaks for its members (env.scene.*)."""
    return key in DOCUMENTED or any(key.startswith(f"{parent}.") for parent in ("env.scene", "hydra"))


def test_every_key_of_every_env_and_task_config_has_an_entry():
    missing = set()
    with initialize_config_dir(config_dir=str(REPO / "conf"), version_base="1.3"):
        for env in ("rigid_fall", "fluid_cube", "mass_rope"):
            missing |= {k for k in leaf_keys(compose("config", overrides=[f"env={env}", "experiment=none"])) if not documented(k)}
        for task in sorted(p.stem for p in (REPO / "conf" / "task").glob("*.yaml")):
            missing |= {k for k in leaf_keys(compose("config", overrides=[f"task={task}", "experiment=none"])) if not documented(k)}
    assert not missing, f"config keys with no entry in docs/configuration.md: {sorted(missing)}"


def test_the_entries_name_only_keys_that_exist():
    with initialize_config_dir(config_dir=str(REPO / "conf"), version_base="1.3"):
        keys = set()
        for env in ("rigid_fall", "fluid_cube", "mass_rope"):
            keys |= set(leaf_keys(compose("config", overrides=[f"env={env}", "experiment=none"])))
        for task in sorted(p.stem for p in (REPO / "conf" / "task").glob("*.yaml")):
            keys |= set(leaf_keys(compose("config", overrides=[f"task={task}", "experiment=none"])))
    groups = {"experiment", "per_env"}  # the groups table's rows: chosen, not keys of the composed config
    stale = {k for k in DOCUMENTED - groups if k not in keys}
    assert not stale, f"docs/configuration.md documents keys no config has: {sorted(stale)}"
