"""task=compare: evaluations of one test set paired video by video against a reference evaluation
(vgpl.eval.compare): parameter MAE and future error, each difference with its bootstrap interval.
Writes compare.md, compare.csv and compare.json (the unrounded numbers) to ``paths.output_dir``."""

from __future__ import annotations

import json
from pathlib import Path

from omegaconf import DictConfig

from vgpl.eval.compare import compare_rows, paired_comparisons, read_record, short_names
from vgpl.eval.tables import csv_text, markdown


def compare(cfg: DictConfig) -> dict:
    spec = cfg.task
    if spec.get("reference") in (None, "???") or spec.get("others") in (None, "???"):
        raise ValueError("task=compare needs task.reference=<a task=evaluate output folder> and task.others='[<folder>,...]'")
    others = [str(o) for o in ([spec.others] if isinstance(spec.others, str) else spec.others)]
    if len({str(spec.reference), *others}) <= len(others):
        raise ValueError(f"task.reference={spec.reference}, task.others={others}: each evaluation folder once, expected")
    reference, *names = short_names([str(spec.reference), *others])  # the table's labels; compare.json keeps the paths
    comparisons = paired_comparisons(read_record(spec.reference), {n: read_record(o) for n, o in zip(names, others)}, reference)
    header, rows = compare_rows(comparisons, reference)
    out = Path(cfg.paths.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    where = "\n".join(f"- {n}: {p}" for n, p in zip([reference, *names], [str(spec.reference), *others]))
    text = f"# Paired against {reference}\n\n{where}\n\n" + markdown(header, rows) + "\n"
    (out / "compare.md").write_text(text)
    (out / "compare.csv").write_text(csv_text(header, rows))
    (out / "compare.json").write_text(json.dumps({"reference": str(spec.reference), "paths": dict(zip(names, others)), "comparisons": comparisons}, indent=1))
    print(text)
    return {"compared": len(others), "rows": len(rows), "report": str(out / "compare.md")}
