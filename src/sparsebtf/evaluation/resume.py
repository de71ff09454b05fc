"""Checkpoints of ``sparsebtf bench quality`` (``--resume``): an interrupted run continues.

A run writes, atomically, into ``OUT/partial/``:

* ``run.json``: what the checkpoints belong to (the :class:`~.benchmark_set.BenchConfig`, the
  seed, the extra materials, every method's name and class, the library version) and how
  many times the run was resumed;
* ``methods.pkl``: after each method's fit, the list of all the run's
  :class:`~.methods.Method` objects (one pickle, so that objects that refer to each other
  still do) and how many of them are fitted;
* ``material-NNN.pkl``: after each material (test, Table 5, true black, in the run's order),
  what it added to the results (rows, material values, grids, Figures 5 and 8, decode speed).

Every checkpoint holds the run's timings and elapsed seconds so far, so a resumed run's
``timings_seconds`` add up the pieces' times (the work of an interrupted piece after its last
checkpoint is done again and counted once). ``--resume`` with other settings than the
checkpoints' is refused with one line naming what differs; checkpoints without ``--resume``
are refused with one line suggesting it (as ``encode --resume`` and ``train --resume``). The
folder is removed once ``results.json`` is written. The pickles are the run's own: load only
checkpoints that you wrote.
"""

from __future__ import annotations

import json
import pickle
import shutil
from dataclasses import asdict
from pathlib import Path
from typing import Any

from .._atomic import atomic_output
from .._json import json_default
from .._version import library_version
from ..errors import SparseBTFError

__all__ = ["PARTIAL", "Progress"]

#: the checkpoints' folder inside the run's output folder
PARTIAL = "partial"


def _identity(cfg: Any, seed: int, extra: Any, methods: Any) -> dict[str, Any]:
    """What a run's checkpoints belong to, as JSON values (compared field by field)."""
    ident = {
        "config": asdict(cfg),
        "seed": seed,
        "extra_materials": [str(e) for e in extra],
        "methods": [f"{m.name}={type(m).__module__}:{type(m).__qualname__}" for m in methods],
        "library": library_version(),
    }
    return json.loads(json.dumps(ident, default=json_default))


def _differences(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    diff = [k for k in new if k != "config" and old.get(k) != new[k]]
    oc, nc = old.get("config", {}), new["config"]
    diff += [f"config.{k}" for k in sorted(set(oc) | set(nc)) if oc.get(k) != nc.get(k)]
    return diff


class Progress:
    """The checkpoints of one run in ``folder`` (``OUT/partial``); inactive writes nothing."""

    def __init__(self, folder: Path, resume: bool, cfg: Any, seed: int, extra: Any,
                 methods: Any) -> None:  # fmt: skip
        self.folder = folder
        self.ident = _identity(cfg, seed, extra, methods)
        found = sorted(p.name for p in folder.glob("*")) if folder.is_dir() else []
        if resume and "run.json" not in found:
            raise SparseBTFError(
                f"--resume: no checkpoint in {folder} (an interrupted 'sparsebtf bench quality' "
                "with the same --out leaves one there)"
            )
        if found and not resume:
            raise SparseBTFError(
                f"{folder} holds the checkpoints of an earlier run; add --resume to continue "
                "it, or delete the folder to start over"
            )
        self.resumed = 0
        if resume:
            try:
                old = json.loads((folder / "run.json").read_text())
            except (OSError, ValueError) as e:
                raise SparseBTFError(f"--resume: cannot read {folder / 'run.json'} ({e}); "
                                     "delete the folder to start over") from None  # fmt: skip
            if diff := _differences(old.get("identity", {}), self.ident):
                raise SparseBTFError(
                    f"--resume: the checkpoints in {folder} are of a run with other "
                    f"{', '.join(diff)}; rerun with its settings, or delete the folder to "
                    "start over"
                )
            self.resumed = int(old.get("resumed", 0)) + 1
        folder.mkdir(parents=True, exist_ok=True)
        self._write_json("run.json", {"identity": self.ident, "resumed": self.resumed})

    # -- writing ---------------------------------------------------------------------------
    def _write_json(self, name: str, value: Any) -> None:
        with atomic_output(self.folder / name) as tmp:
            tmp.write_text(json.dumps(value, indent=2, default=json_default))

    def _write(self, name: str, value: Any) -> None:
        with atomic_output(self.folder / name) as tmp, open(tmp, "wb") as f:
            pickle.dump(value, f, protocol=pickle.HIGHEST_PROTOCOL)

    def _read(self, name: str) -> Any:
        path = self.folder / name
        if not path.is_file():
            return None
        try:
            with open(path, "rb") as f:
                return pickle.load(f)
        except Exception as e:  # a checkpoint of another library version, a truncated copy
            raise SparseBTFError(f"--resume: cannot read the checkpoint {path} "
                                 f"({type(e).__name__}: {e}); delete the folder to start "
                                 "over") from None  # fmt: skip

    def save_methods(self, methods: list[Any], fitted: int, timings: dict[str, float],
                     seconds: float) -> None:  # fmt: skip
        """All the run's methods, the first ``fitted`` of them fitted."""
        self._write("methods.pkl", {"methods": methods, "fitted": fitted,
                                    "timings": dict(timings), "seconds": seconds})

    def save_material(self, index: int, record: dict[str, Any], timings: dict[str, float],
                      seconds: float) -> None:  # fmt: skip
        """What material ``index`` of the run's order added to the results."""
        self._write(f"material-{index:03d}.pkl",
                    {**record, "timings": dict(timings), "seconds": seconds})

    # -- reading ---------------------------------------------------------------------------
    def methods(self) -> dict[str, Any] | None:
        """The saved methods (keys ``methods``, ``fitted``, ``timings``, ``seconds``)."""
        return self._read("methods.pkl")

    def material(self, index: int) -> dict[str, Any] | None:
        return self._read(f"material-{index:03d}.pkl")

    def latest(self) -> dict[str, Any] | None:
        """The last checkpoint's timings and seconds (None before any)."""
        names = sorted(p.name for p in self.folder.glob("material-*.pkl"))
        rec = self._read(names[-1]) if names else self.methods()
        return None if rec is None else {"timings": rec["timings"], "seconds": rec["seconds"]}

    def finish(self) -> None:
        """The run is complete: its checkpoints have served their purpose."""
        shutil.rmtree(self.folder, ignore_errors=True)
