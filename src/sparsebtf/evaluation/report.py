"""``results.md`` from a ``bench quality`` results object, and ``bench report``.

Everything is computed from ``results.json`` rows — no number is typed by hand — so
``sparsebtf bench report DIR --docs docs`` regenerates ``docs/results.md`` from any run, old
ones included. The parts live in their own modules: the row queries (:mod:`.rows`), the
verdicts (:mod:`.verdicts`, :mod:`.claims3`), the tables (:mod:`.tables`), the plots
(:mod:`.plots`), the page's text (:mod:`.results_md`, :mod:`.sections`); this module
writes the files.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

from .._atomic import atomic_output
from .._json import json_default
from ..errors import BTFInputError
from .adaptive_verdicts import adaptive_figures
from .history import record
from .plots import figure3, learning_curves, quality_storage

# the page's text; rule_line, objective_line and _budgets_table, this module's until they
# moved, stay importable from here
from .results_md import objective_line, render_markdown, rule_line
from .sections import _budgets_table  # noqa: F401
from .side_runs import side_runs_section
from .tables import (
    STORAGE_JSON,
    stored_levels,
    table2,
    table3,
    table5,
    table_black,
    table_storage,
    table_stored,
)
from .verdicts import summarise

__all__ = [
    "STORAGE_JSON",
    "figure3",
    "objective_line",
    "previous_record",
    "quality_storage",
    "regenerate",
    "render_markdown",
    "rule_line",
    "stored_levels",
    "summarise",
    "table2",
    "table3",
    "table5",
    "table_black",
    "table_storage",
    "table_stored",
    "write_report",
]  # fmt: skip


def write_report(result: dict[str, Any], out: str | os.PathLike[str]) -> dict[str, Any]:
    """Write tables (Markdown), figure3.png, quality_storage.png and results.md into ``out``.

    Adds ``summary`` (verdicts) to ``result`` and returns it. A ``previous`` record in
    ``result`` (:func:`~.history.record`) adds how each verdict moved from that run.
    """
    out = Path(out)
    summary = summarise(result)
    result["summary"] = summary
    figure3(result, out / "figure3.png")
    quality_storage(result, out / "quality_storage.png")
    learning_curves(result, out / "learning_curves.png")
    for name, fn in (("table2.md", table2), ("table3.md", table3), ("table5.md", table5)):
        with atomic_output(out / name) as tmp:
            tmp.write_text(fn(result) + "\n")
    with atomic_output(out / "results.md") as tmp:
        tmp.write_text(render_markdown(result, summary, previous=result.get("previous")))
    return summary


def previous_record(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The :func:`~.history.record` of the run whose ``results.json`` is at ``path``."""
    try:
        prev = json.loads(Path(path).read_text())
        return record(prev, prev.get("summary") or summarise(prev))
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise BTFInputError(
            f"--previous {path}: not a readable 'bench quality' results.json ({e})"
        ) from e


def _captured_run(
    result: dict[str, Any], docs: Path, folder: str | os.PathLike[str] | None
) -> tuple[dict[str, Any], dict[str, Any], str | None] | None:
    """(results, summary, link to its results.md) of the captured run for ``result``'s
    results.md, or None (see :func:`regenerate`)."""
    if folder is None:
        if result["config"].get("source") == "capture":
            return None
        folder = docs / "capture" / "results"
        if not (folder / "results.json").exists():
            return None
    path = Path(folder) / "results.json"
    try:
        cap = json.loads(path.read_text())
        if cap["config"].get("source") != "capture":
            raise BTFInputError(f"--captured {folder}: {path} is not a '--source capture' run")
        summary = cap.get("summary") or summarise(cap)
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise BTFInputError(f"--captured {folder}: not a readable 'bench quality' results.json "
                            f"({e})") from e  # fmt: skip
    page = next((p for p in (Path(folder) / "results.md", Path(folder).parent / "results.md")
                 if p.exists()), None)  # fmt: skip
    return cap, summary, None if page is None else os.path.relpath(page, docs)


def regenerate(
    run_dir: str | os.PathLike[str],
    docs: str | os.PathLike[str],
    previous: str | os.PathLike[str] | None = None,
    captured: str | os.PathLike[str] | None = None,
) -> Path:
    """``docs/results.md``, ``docs/results/*.png`` and ``docs/results/results.json`` from a
    finished run's ``results.json``.

    ``captured``: the folder of a ``--source capture`` run (its ``results.json``), whose
    verdicts go beside this run's; by default ``DOCS/capture/results`` when it holds one
    (``sparsebtf bench report CAPTURE_RUN --docs DOCS/capture`` puts it there) and this run is
    not a captured one itself.

    Beside each verdict goes how it moved from a previous run: the ``results.json`` at
    ``previous``; else the run's own ``previous`` record; else the run that ``docs`` held
    until now (``docs/results/results.json``), which this call then replaces. A
    ``benchmarks/bench_storage.py --json`` output named :data:`STORAGE_JSON` in the run's
    folder (else in ``docs/results/``) adds the "stored bytes vs Table 4" section.
    """
    run = Path(run_dir)
    result = json.loads((run / "results.json").read_text())
    summary = summarise(result)
    docs = Path(docs)
    img_dir = docs / "results"
    for folder in (run, img_dir):
        if (folder / STORAGE_JSON).exists():
            result["storage"] = json.loads((folder / STORAGE_JSON).read_text())
            if not (img_dir / STORAGE_JSON).exists() or not (
                    img_dir / STORAGE_JSON).samefile(folder / STORAGE_JSON):  # fmt: skip
                shutil.copyfile(folder / STORAGE_JSON, img_dir / STORAGE_JSON)
            break
    img_dir.mkdir(parents=True, exist_ok=True)
    held = img_dir / "results.json"
    if previous is not None:
        result["previous"] = previous_record(previous)
    elif "previous" not in result and held.exists():
        prev = json.loads(held.read_text())
        if prev.get("created") != result.get("created"):
            result["previous"] = record(prev, prev.get("summary") or summarise(prev))
    result["summary"] = summary
    figure3(result, img_dir / "figure3.png")
    quality_storage(result, img_dir / "quality_storage.png")
    learning_curves(result, img_dir / "learning_curves.png")
    figure8 = ["figure8/figure8.png"] if (result.get("figure8") or {}).get("methods") else []
    for g in [*result.get("grids", []), *figure8, *adaptive_figures(result)]:
        src, dst = run / g, img_dir / Path(g).name
        if src.exists() and not (dst.exists() and src.samefile(dst)):
            shutil.copyfile(src, dst)
    with atomic_output(held) as tmp:  # the storage figures stay in their own file
        kept = {k: v for k, v in result.items() if k != "storage"}
        tmp.write_text(json.dumps(kept, indent=2, default=json_default))
    target = docs / "results.md"
    text = render_markdown(result, summary, img="results/", previous=result.get("previous"),
                           captured=_captured_run(result, docs, captured),
                           side_runs=side_runs_section(docs))
    text = text.replace(
        "from `results.json`;",
        f"from `results.json` (regenerate: `sparsebtf bench report {img_dir} --docs {docs}`);",
    )
    with atomic_output(target) as tmp:
        tmp.write_text(text)
    return target
