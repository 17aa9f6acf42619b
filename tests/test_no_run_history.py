"""The project speaks of itself, not of the runs that built it: no numbered work periods, run
shorthands ("s42") or ticket numbers in the README, docs, code, configs or tests; and no citation of
files that are not in the repository. The words this file looks for are split in its own source
("sess" "ion"), so that a plain grep of the project finds none either."""

from __future__ import annotations

import re

from tests.conftest import REPO

HISTORY = re.compile(r"\bsess" r"ions?\b|\bs\d{1,3}(?:-\d{1,3})?\b|\biss" r"ues? #?\d+\b|(?-i:\bREFERENCE\.md|\bDESIGN\.md)", re.IGNORECASE)
ALLOWED = re.compile(r"start_new_sess" r"ion")  # subprocess.Popen's argument, not a work period


def project_files() -> list:
    files = [REPO / "README.md", REPO / "run.py", REPO / "pyproject.toml"]
    for folder, patterns in (("docs", ("*.md",)), ("src", ("*.py",)), ("conf", ("*.yaml",)), ("tests", ("*.py",)),
                             ("benchmarks", ("*.py", "*.md")), ("notebooks", ("*.ipynb",)), ("scripts", ("*.sh", "*.py"))):
        for pattern in patterns:
            files += sorted((REPO / folder).rglob(pattern))
    return [f for f in files if f.is_file() and "egg-info" not in str(f)]


def test_no_run_history_or_outside_citations():
    hits = []
    for path in project_files():
        if path == REPO / "tests" / "test_no_run_history.py":
            continue
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if HISTORY.search(ALLOWED.sub("", line)):
                hits.append(f"{path.relative_to(REPO)}:{number}: {line.strip()[:120]}")
    assert len(project_files()) > 100
    assert not hits, f"{len(hits)} lines name a numbered work period, run or ticket:\n" + "\n".join(hits[:60])


def test_the_pattern_catches_what_it_is_for():
    for text in ("sess" "ion 80's run", "Sess" "ions 23-24", "(s81)", "s46-47", "iss" "ue 4", "see REFERENCE.md"):
        assert HISTORY.search(text), text
    for text in ("docs/design.md", "sess" "ions_dir", "the s-wave", "step s", "shape s1x", "start_new_sess" "ion=True"):
        assert not HISTORY.search(ALLOWED.sub("", text)), text


SCRIPT = re.compile(r"[A-Za-z0-9_./-]*\b[A-Za-z0-9_]+\.py\b")
OUTSIDE = {"models.py"}  # the authors' DPI-Net file that benchmarks/dynamics.py's reference figures time, named as theirs


def test_docs_name_only_scripts_the_repository_holds():
    held = {p.name for p in REPO.rglob("*.py") if not any(part.startswith(".") for part in p.relative_to(REPO).parts)}  # not .git, .venv-test
    docs = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md")), *sorted((REPO / "notebooks").glob("*.ipynb"))]
    missing = [f"{path.relative_to(REPO)}: {name}" for path in docs for name in sorted(set(SCRIPT.findall(path.read_text())))
               if name.rsplit("/", 1)[-1] not in held | OUTSIDE]
    assert len(held) > 100
    assert not missing, "docs name scripts that are not in the repository:\n" + "\n".join(missing)


def test_the_script_pattern_finds_a_missing_script():
    assert SCRIPT.findall("(0.94 by frame 13; `prior_fall_acceleration.py`)") == ["prior_fall_acceleration.py"]
    assert SCRIPT.findall("python benchmarks/inference.py --env rigid_fall") == ["benchmarks/inference.py"]
