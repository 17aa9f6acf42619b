"""The install is reproducible and CI runs what the README says: constraints.txt pins every package
that pyproject.toml asks for (torch aside, which scripts/install.sh installs itself), and .ci/run's
command is the README's test command."""

from __future__ import annotations

import importlib.metadata
import re

from tests.conftest import REPO


def _name(requirement: str) -> str:
    return re.split(r"[<>=!~\[; ]", requirement, maxsplit=1)[0].lower().replace("_", "-")


def _pins() -> dict[str, str]:
    lines = [line.strip() for line in (REPO / "constraints.txt").read_text().splitlines()]
    pins = dict(line.split("==", 1) for line in lines if line and not line.startswith("#"))
    return {name.lower().replace("_", "-"): version for name, version in pins.items()}


def test_constraints_pin_every_dependency_but_torch():
    wanted = {_name(r) for r in importlib.metadata.requires("vgpl")}  # pyproject.toml's dependencies and the test extra
    pins = _pins()
    assert "torch" in wanted and "pytest" in wanted
    assert "torch" not in pins, "torch is installed by scripts/install.sh, so a CUDA build on a GPU machine stays in place"
    assert sorted(wanted - {"torch"} - pins.keys()) == [], "run scripts/refresh_constraints.sh after adding a dependency"
    assert all(re.fullmatch(r"[0-9][0-9A-Za-z.+-]*", v) for v in pins.values()), "every line is name==version"


def test_ci_runs_the_readmes_test_command_in_a_new_virtualenv():
    readme = (REPO / "README.md").read_text()
    quick_start = re.search(r"## Quick start.*?```bash\n(.*?)```", readme, re.DOTALL).group(1).splitlines()
    ci = [line for line in (REPO / ".ci/run").read_text().splitlines() if line and not line.startswith(("#", "set ", "cd "))]
    assert len(quick_start) == 2 and ci == [quick_start[1].split("#")[0].strip()]
    test_script = (REPO / "scripts/test.sh").read_text()
    assert "bash scripts/install.sh .venv-test" in test_script and ".venv-test/bin/python -m pytest" in test_script
    assert "--clear" in (REPO / "scripts/install.sh").read_text()  # a virtualenv already there is replaced, not reused
