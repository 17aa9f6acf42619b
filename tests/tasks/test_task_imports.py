"""The task modules import one another in one direction only: no cycle, lazy imports included."""

from __future__ import annotations

import ast

from tests.conftest import REPO

TASKS = REPO / "src" / "vgpl" / "tasks"


def task_imports() -> dict[str, set[str]]:
    """Each task module -> the task modules it imports anywhere in its body (top level or in a function)."""
    graph = {}
    for path in sorted(TASKS.glob("*.py")):
        found = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("vgpl.tasks."):
                found.add(node.module.removeprefix("vgpl.tasks."))
            elif isinstance(node, ast.Import):
                found |= {a.name.removeprefix("vgpl.tasks.") for a in node.names if a.name.startswith("vgpl.tasks.")}
        graph[path.stem] = found - {path.stem}
    return graph


def cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle as a list of modules, or None."""
    state: dict[str, int] = {}

    def visit(node: str, path: list[str]) -> list[str] | None:
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt] if nxt in path else [node, nxt]
            if nxt not in state and (found := visit(nxt, [*path, nxt])):
                return found
        state[node] = 2
        return None

    for start in sorted(graph):
        if start not in state and (found := visit(start, [start])):
            return found
    return None


def test_the_cycle_finder_finds_one():
    assert cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert cycle({"a": {"b"}, "b": set()}) is None


def test_no_import_cycle_between_task_modules():
    graph = task_imports()
    assert {"pipeline", "evaluate", "baseline", "stage"} <= set(graph) and "stage" in graph["baseline"]
    assert cycle(graph) is None, f"task modules import each other in a cycle: {' -> '.join(cycle(graph))}"
