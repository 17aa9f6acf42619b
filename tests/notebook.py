"""Execute a notebook in a fresh Jupyter kernel, the way a researcher would run it.

As papermill does, the values given are injected in a cell right after the cell tagged
``parameters``, so the notebook's own defaults stay visible and tested code is the shipped code.
"""

from __future__ import annotations

from pathlib import Path

import nbformat
from nbclient import NotebookClient


def run_notebook(path: str | Path, cwd: str | Path, **parameters) -> nbformat.NotebookNode:
    """Run ``path`` with working directory ``cwd``; returns the executed notebook (outputs filled).
    Raises nbclient's CellExecutionError, naming the cell, when a cell fails."""
    nb = nbformat.read(str(path), as_version=4)
    tagged = [k for k, c in enumerate(nb.cells) if "parameters" in c.metadata.get("tags", [])]
    if parameters:
        assert tagged, f"{path}: no cell tagged 'parameters' to override"
        lines = ["from pathlib import Path"] + [f"{k} = {_literal(v)}" for k, v in parameters.items()]
        nb.cells.insert(tagged[0] + 1, nbformat.v4.new_code_cell("\n".join(lines)))
    NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(cwd)}}).execute()
    return nb


def _literal(value) -> str:
    """Python source for a parameter value (paths become Path('...'))."""
    return f"Path({str(value)!r})" if isinstance(value, Path) else repr(value)


def text_output(nb: nbformat.NotebookNode) -> str:
    """Everything the notebook printed (stream and plain-text results), in order."""
    parts = []
    for cell in nb.cells:
        for out in cell.get("outputs", []):
            parts.append(out.get("text", "") or out.get("data", {}).get("text/plain", ""))
    return "\n".join(parts)


def output_types(nb: nbformat.NotebookNode) -> set[str]:
    """MIME types of every rich output (e.g. image/gif, image/png)."""
    return {mime for cell in nb.cells for out in cell.get("outputs", []) for mime in out.get("data", {})}
