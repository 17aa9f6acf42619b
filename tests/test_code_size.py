"""Every function in src/ fits on a screen: at most 60 lines, its docstring included. A longer one
fails here with its file, name and length; split it into functions that say what each part does."""

from __future__ import annotations

import ast

from tests.conftest import REPO

MAX_LINES = 60


def function_lengths(source: str) -> dict[str, int]:
    """Each function's and method's qualified name -> its lines, decorators excluded."""
    lengths = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = f"{prefix}{child.name}"
                if not isinstance(child, ast.ClassDef):
                    lengths[name] = child.end_lineno - child.lineno + 1
                visit(child, f"{name}.")

    visit(ast.parse(source), "")
    return lengths


def test_function_lengths_are_measured_by_their_own_lines():
    source = "class A:\n    def f(self):\n        def g():\n            pass\n        return 1\n\n\ndef h():\n    return 2\n"
    assert function_lengths(source) == {"A.f": 4, "A.f.g": 2, "h": 2}


def test_no_function_in_src_is_over_60_lines():
    long = {f"{path.relative_to(REPO)}::{name}": n for path in sorted((REPO / "src").rglob("*.py"))
            for name, n in function_lengths(path.read_text()).items() if n > MAX_LINES}
    assert not long, f"functions over {MAX_LINES} lines: {long}"
