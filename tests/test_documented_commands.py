"""The commands and config keys the user-facing docs (README.md, docs/*.md) give must still
compose with Hydra, as the notebooks must still run: a renamed or removed option breaks a test here,
not the first researcher who pastes the command. Every link in README.md and docs/*.md must reach a
file or a heading.

Every ``python run.py ...`` command (fenced blocks, backslash continuations joined, and inline code),
each point of a ``-m`` sweep, is composed from conf/ and resolved, and its task must exist. Inline
``key=value`` overrides and bare config keys in the prose are checked against the ``standard`` preset
(``task.*`` keys against the task config that defines them, ``env.*`` keys against the env that has
them). Placeholders a reader fills in (``<env>``, ``<preset>``, ...) take
a real value; commands elided with ``...`` or shell variables are skipped, and counted.
"""

from __future__ import annotations

import itertools
import re
import shlex
from pathlib import Path

import pytest
import yaml
from hydra import compose, initialize_config_dir
from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import HydraException
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

import vgpl  # noqa: F401  (registers the config resolvers)
from vgpl.tasks import TASKS

REPO = Path(__file__).resolve().parents[1]
DOCS = ["README.md", *(f"docs/{p.name}" for p in sorted((REPO / "docs").glob("*.md")))]
BROKEN = (HydraException, OmegaConfBaseException, AssertionError)  # a bad override or group, an unresolvable value, an unknown task
PLACEHOLDERS = {"<env>": "rigid_fall", "<preset>": "quick", "<s>": "0", "<partition>": "debug", "<date>/<time>": "2026-01-01/00-00-00"}
COMMAND = re.compile(r"python run\.py[^#&;|\n]*")  # up to a comment, &&, ; or a pipe (a redirect: strip_redirect)


def strip_redirect(command: str) -> str:
    """``python run.py a=b > log 2>&1`` -> ``python run.py a=b`` (a ``>`` inside a word, as in <run>, stays)."""
    return re.split(r"\s\d?>", command)[0]


def documented_commands(text: str) -> list[str]:
    """Every ``python run.py ...`` in fenced blocks (continuations joined) and inline code spans."""
    blocks = re.findall(r"```[a-z]*\n(.*?)```", text, re.DOTALL)
    found = [m for block in blocks for m in COMMAND.findall(block.replace("\\\n", " "))]
    outside = re.sub(r"```.*?```", "", text, flags=re.DOTALL)
    found += [m for span in re.findall(r"`([^`]*python run\.py[^`]*)`", outside) for m in COMMAND.findall(span)]
    return [" ".join(strip_redirect(c).split()) for c in found]


def fill_placeholders(command: str) -> str:
    for placeholder, value in PLACEHOLDERS.items():
        command = command.replace(placeholder, value)
    return command


def is_elided(command: str) -> bool:
    return "..." in command or "$" in command or re.search(r"<[^>]*>", command) is not None


def sweep_points(overrides: list[str]) -> list[list[str]]:
    """A ``-m`` command's overrides -> one override list per job of its sweep."""
    choices = []
    for override in OverridesParser.create().parse_overrides(overrides):
        if override.is_sweep_override():
            choices.append([f"{override.get_key_element()}={value}" for value in override.sweep_string_iterator()])
        else:
            choices.append([override.input_line])
    return [list(point) for point in itertools.product(*choices)]


def compose_resolved(overrides: list[str]):
    """The job's config as run.py composes it, every interpolation resolved (raises where one fails)."""
    cfg = compose("config", overrides=overrides, return_hydra_config=True)
    HydraConfig.instance().set_config(cfg)  # ${hydra:...} interpolations read it
    OmegaConf.to_container(OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"]), resolve=True)
    return cfg


@pytest.fixture(scope="module")
def docs_text() -> dict[str, str]:
    return {name: (REPO / name).read_text() for name in DOCS}


@pytest.fixture(scope="module")
def hydra_conf():
    with initialize_config_dir(config_dir=str(REPO / "conf"), version_base="1.3"):
        yield


def test_extraction_reads_fenced_continued_and_inline_commands() -> None:
    text = ("Run `python run.py task=demo` first.\n```bash\nbash scripts/install.sh && python run.py   # main job\n"
            "python run.py -m task=evaluate \\\n    env=rigid_fall,mass_rope > log.txt\n```\n")
    assert documented_commands(text) == ["python run.py", "python run.py -m task=evaluate env=rigid_fall,mass_rope", "python run.py task=demo"]
    assert sweep_points(["task=evaluate", "env=rigid_fall,mass_rope"]) == [["task=evaluate", "env=rigid_fall"], ["task=evaluate", "env=mass_rope"]]
    assert is_elided("python run.py task=train_inference ... seed=1") and is_elided("python run.py $A")
    assert documented_commands("`python run.py task=evaluate_dynamics ckpt_path=outputs/<run>/last.ckpt`") == [
        "python run.py task=evaluate_dynamics ckpt_path=outputs/<run>/last.ckpt"]  # a placeholder's > is not a redirect
    assert not is_elided(fill_placeholders("python run.py env=<env> experiment=<preset>"))


@pytest.mark.slow  # composes every documented command: ~20 s
def test_every_documented_command_composes(docs_text, hydra_conf) -> None:
    checked, failures = 0, []
    for name, text in docs_text.items():
        for command in documented_commands(text):
            command = fill_placeholders(command)
            if is_elided(command):
                continue
            overrides = [w for w in shlex.split(command)[2:] if w != "-m"]
            try:
                points = sweep_points(overrides)
            except BROKEN as error:
                failures.append(f"{name}: {command}\n    {type(error).__name__}: {str(error).splitlines()[0]}")
                continue
            for point in points:
                try:
                    task = compose_resolved(point).task.name
                    assert task in TASKS, f"task.name={task!r} is not a task ({sorted(TASKS)})"
                    checked += 1
                except BROKEN as error:  # every broken command is listed, not only the first
                    failures.append(f"{name}: {command}\n    {' '.join(point)}\n    {type(error).__name__}: {str(error).splitlines()[0]}")
    assert not failures, "documented commands that no longer compose:\n" + "\n".join(failures)
    assert checked >= 50, f"only {checked} documented commands were composed: has the extraction broken?"


def has_key(cfg, dotted: str) -> bool:
    """Whether ``dotted`` names a key of cfg, whatever its value (null and ??? included)."""
    parent, _, leaf = dotted.rpartition(".")
    node = OmegaConf.select(cfg, parent, throw_on_missing=False, throw_on_resolution_failure=False) if parent else cfg
    return OmegaConf.is_dict(node) and leaf in node.keys()  # noqa: SIM118 (`in node` is False for a ??? value)


def task_defining(key: str) -> str | None:
    """The task config (conf/task/<name>.yaml) that has ``task.<key>``, if any."""
    for path in sorted((REPO / "conf" / "task").glob("*.yaml")):
        if has_key(OmegaConf.load(path), key.removeprefix("task.")):
            return path.stem
    return None


def mass_rope_scene_keys() -> set[str]:
    """The keys of MassRope's scene that the default env's scene lacks."""
    scene = lambda env: set(yaml.safe_load((REPO / "conf" / "env" / f"{env}.yaml").read_text())["scene"])  # noqa: E731
    return scene("mass_rope") - scene("rigid_fall")


PARTS = {"inference_scheme": "model.inference.net.scheme", "rollout_target": "model.inference.net.target",
         "rigidness_estimator": "model.inference.net.rigidness_estimator"}  # the inference module's part groups and where they go


def part_choice(key: str) -> str | None:
    """The part group's choice (``inference_scheme=joint``) whose config has ``key``, for a key of a part."""
    for group, package in PARTS.items():
        if key.startswith(f"{package}."):
            for path in sorted((REPO / "conf" / group).glob("*.yaml")):
                if has_key(OmegaConf.load(path), key.removeprefix(f"{package}.")):
                    return f"{group}={path.stem}"
    return None


def context_for(key: str) -> list[str]:
    """The overrides a prose key is meant with: the standard preset (or the paper's, for the keys
    only it sets), and the task, launcher or part choice it belongs to."""
    context = ["experiment=standard"]
    if key.startswith("task.") and (task := task_defining(key)):
        context.append(f"task={task}")
    if key.startswith("hydra.launcher."):
        context.append("hydra/launcher=slurm")
    if choice := part_choice(key):  # a key of one choice of a part group
        context.append(choice)
    if key.startswith("env.scene.") and key.split(".")[2] in mass_rope_scene_keys():  # MassRope's scene alone has them
        context.append("env=mass_rope")
    return context


def test_every_documented_override_and_config_key_exists(docs_text, hydra_conf) -> None:
    text = "\n".join(docs_text.values())
    overrides = sorted(set(re.findall(r"`([a-z_]+(?:\.[a-z_0-9]+)+=[^`\s]+)`", text)))
    keys = sorted(set(re.findall(r"`((?:model|data|trainer|eval|task|env|paths|ckpt)(?:\.[a-z_0-9]+)+)`", text)))
    failures = []
    for override in overrides:
        key, value = override.split("=", 1)
        if is_elided(value):
            continue
        try:
            compose("config", overrides=[*context_for(key), override], return_hydra_config=True)
        except BROKEN as error:
            failures.append(f"`{override}`: {str(error).splitlines()[0]}")
    composed = {}  # one config per context (a handful), not one per key
    for key in keys:
        standard = tuple(context_for(key))
        paper = tuple(o.replace("experiment=standard", "experiment=paper") for o in standard)  # the paper preset's recipe table
        for context in (standard, paper):
            if context not in composed:
                composed[context] = compose("config", overrides=list(context))
        if not any(has_key(composed[context], key) for context in (standard, paper)):
            failures.append(f"`{key}`: no such key in the standard or paper preset's config{' or any task config' if key.startswith('task.') else ''}")
    assert not failures, "documented config keys that no longer exist:\n" + "\n".join(failures)
    assert len(overrides) >= 12 and len(keys) >= 100, (len(overrides), len(keys))  # the extraction still finds them


def github_anchor(heading: str) -> str:
    """The id GitHub gives a Markdown heading: lower case, punctuation other than - and _ dropped, spaces as -."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_every_link_in_the_docs_reaches_a_file_or_a_heading() -> None:
    """Relative links resolve from the linking file's folder (as GitHub renders them), anchors to one
    of its headings (a repeated heading's later ids get -1, -2, ...)."""
    assert github_anchor("Results (standard preset; 2 cores)") == "results-standard-preset-2-cores"
    broken = []
    for doc in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]:
        text = doc.read_text()
        anchors, seen = set(), {}
        for heading in re.findall(r"^#{1,6} (.+)$", re.sub(r"```.*?```", "", text, flags=re.DOTALL), flags=re.MULTILINE):
            base = github_anchor(heading)
            anchors.add(base if base not in seen else f"{base}-{seen[base]}")
            seen[base] = seen.get(base, 0) + 1
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+://", target):
                continue
            path, _, anchor = target.partition("#")
            if path and not (doc.parent / path).exists():
                broken.append(f"{doc.relative_to(REPO)}: ({target}) is no file")
            elif anchor and not path and anchor not in anchors:
                broken.append(f"{doc.relative_to(REPO)}: (#{anchor}) is no heading of it")
    assert not broken, "\n".join(broken)
