"""The beyond-the-paper verdicts measured by runs of their own, in ``docs/results.md``.

The training variants (issue 34, ``docs/training-variants``), adaptive patch sizes (issue
35, ``docs/adaptive-patches``) and Table 3 at the paper's 100×100 crops (``bench quality
--paper-crop``, ``docs/paper-crop``) are benchmark methods the default run does not include; their
runs (``bench quality --methods …``, synthetic and ``--source capture``) are regenerated into
folders of their own by ``sparsebtf bench report RUN --docs docs/<name>[/capture]``; a rerun
at another ``--seed`` (other materials, other training points) goes into a ``seed<N>``
folder under either (``docs/<name>/seed1``, ``docs/<name>/capture/seed1``). This module
collects their verdict rows (from each run's stored ``summary``) into one table of the main
page, one line per run in each cell, with each run's configuration and a link to its page, so
the page carries every verdict the project has measured.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from .adaptive_verdicts import ADAPTIVE_KEYS
from .claims3 import TABLE3_KEYS
from .training_verdicts import TRAINING_KEYS

__all__ = ["SIDE_RUNS", "side_runs_section"]

#: (docs sub-folder, the verdict keys its runs carry)
SIDE_RUNS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("training-variants", TRAINING_KEYS),
    ("adaptive-patches", ADAPTIVE_KEYS),
    ("paper-crop", TABLE3_KEYS),
)


def _read(folder: Path) -> dict[str, Any] | None:
    """A regenerated run's results.json (with its ``summary``), or None where there is none
    or it is not readable as one."""
    try:
        run = json.loads((folder / "results" / "results.json").read_text())
    except (OSError, ValueError):
        return None
    return run if isinstance(run, dict) and isinstance(run.get("summary"), dict) else None


def _runs(folder: Path) -> list[tuple[str, dict[str, Any]]]:
    """(its sub-folder of ``folder``: "" or "seed<N>/", run) for the run in ``folder`` and its
    reruns in ``folder/seed<N>`` (by N); unreadable ones are left out."""
    found = [("", _read(folder))]
    seeds = [p for p in folder.glob("seed*") if p.name[4:].isdigit()] if folder.is_dir() else []
    found += [(f"{p.name}/", _read(p)) for p in sorted(seeds, key=lambda p: int(p.name[4:]))]
    return [(sub, run) for sub, run in found if run is not None]


def _cell(runs: list[tuple[str, dict[str, Any]]], key: str) -> str:
    cells = []
    for _, run in runs:
        if key in run["summary"]:
            s = run["summary"][key]
            text = f"{s.get('figure', '')}: **{s['verdict']}**".lstrip(": ")
            seed = run.get("seed", 0)
            cells.append(f"seed {seed}: {text}" if len(runs) > 1 or seed else text)
    return "<br>".join(cells) or "not run"


def _run_text(run: dict[str, Any], page: str) -> str:
    cfg = run.get("config", {})
    minutes = float(run.get("seconds", 0.0)) / 60
    return (f"[{cfg.get('name', '?')} configuration, {cfg.get('source', 'synth')}, seed "
            f"{run.get('seed', 0)}]({page}), created {run.get('created', '?')}, "
            f"{minutes:.0f} min")  # fmt: skip


def side_runs_section(docs: str | os.PathLike[str]) -> list[str]:
    """Markdown lines: per side run found under ``docs``, its verdicts on synthetic and on
    captured materials (``docs/<name>/results`` and ``docs/<name>/capture/results``, and
    their reruns at other seeds, ``…/seed<N>/results``), one line per run in a cell; none
    found, no lines."""
    docs = Path(docs)
    rows, runs_text = [], []
    for name, keys in SIDE_RUNS:
        synth, cap = _runs(docs / name), _runs(docs / name / "capture")
        for runs, sub in ((synth, name), (cap, f"{name}/capture")):
            for seed_dir, run in runs:
                runs_text.append(f"- `{name}`: "
                                 + _run_text(run, f"{sub}/{seed_dir}results.md"))  # fmt: skip
        for key in keys:
            found = [r for _, r in synth + cap if key in r["summary"]]
            if found:
                claim = found[0]["summary"][key].get("claim", key)
                rows.append(f"| {claim} | {_cell(synth, key)} | {_cell(cap, key)} |")
    if not rows:
        return []
    return ["", "## Beyond the paper: methods measured in runs of their own", "",
            "Methods and configurations the default run does not include, measured beside the "
            "reference by `sparsebtf bench quality --methods …` (or `--paper-crop`: Table 3 at "
            "the paper's 100x100 crops; each run's page has every table, its command and its "
            "rules):", "", *runs_text, "",
            "| claim | synthetic materials | captured materials |", "|---|---|---|",
            *rows]  # fmt: skip
