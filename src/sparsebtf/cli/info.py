"""``sparsebtf info``: what a file holds, as a table in words (``--json``: the same nested
dictionary as one JSON object)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..data.btf import BTF
from ..open import file_format, open_btf
from ._model import MODEL_HELP
from ._output import nested_rows, print_json, table

__all__ = ["describe", "describe_btf", "register"]


def _directions(btf: BTF) -> dict[str, Any]:
    return {
        "lights": {"name": btf.lights.name, "count": len(btf.lights)},
        "views": {"name": btf.views.name, "count": len(btf.views)},
    }


def describe_btf(btf: BTF, scan: bool = True) -> dict[str, Any]:
    """Shape, directions and (streaming over view blocks) the value range of a BTF."""
    h, w, nl, nv, _ = btf.shape
    out: dict[str, Any] = {
        "kind": "btf",
        "name": btf.name,
        "shape": [h, w, nl, nv, 3],
        "texels": f"{h}x{w}",
        "directions": _directions(btf),
        "raw_bytes_fp16": btf.n_values * 2,
    }
    if scan:
        lo, hi, total, nonfinite = np.inf, -np.inf, 0.0, 0
        for block in btf.iter_blocks():
            finite = np.isfinite(block)
            nonfinite += int((~finite).sum())
            vals = block[finite]
            if vals.size:
                lo, hi = min(lo, float(vals.min())), max(hi, float(vals.max()))
                total += float(vals.sum(dtype=np.float64))
        out["value_range"] = [lo, hi]
        out["mean"] = total / btf.n_values
        out["nonfinite"] = nonfinite
    if btf.attrs:
        out["attrs"] = btf.attrs
    return out


def describe(
    path: str | os.PathLike[str], model_path: str | None = None, scan: bool = True
) -> dict[str, Any]:
    """Describe a dense BTF, model or coded file (or a ``synth:`` spec)."""
    s = str(path)
    if s.startswith("synth:") or s.lower().endswith((".btf", ".zip")):
        out = describe_btf(open_btf(s), scan)
        if not s.startswith("synth:"):
            kind = "ubo2014-btf" if s.lower().endswith(".btf") else "ubo2003-zip"
            out.update(format=kind, file_bytes=Path(s).stat().st_size)
        return out
    fmt = file_format(s)
    size = Path(s).stat().st_size
    if fmt == "sparsebtf-dense":
        out = describe_btf(open_btf(s), scan)
        out.update(format=fmt, file_bytes=size, integrity=_integrity(s))
        return out
    if fmt == "sparsebtf-model":
        from ..storage import load_model

        m = load_model(s)
        return {
            "kind": "model",
            "format": fmt,
            "content_hash": m.content_hash,
            "channels": list(m.channels),
            "n_dictionaries": {ch: m.n_dictionaries(ch) for ch in m.channels},
            "mode_sizes": list(m.mode_sizes),
            "patch": m.patch,
            **({"patch_sizes": list(m.patch_sizes)} if m.patches else {}),
            "directions": {
                "lights": {"name": m.lights.name, "count": len(m.lights)},
                "views": {"name": m.views.name, "count": len(m.views)},
            },
            "params": m.params,
            "training": m.training,
            "provenance": m.provenance,
            "file_bytes": size,
            "integrity": _integrity(s),
        }
    if fmt == "sparsebtf-coded":
        from ..errors import ModelMismatchError
        from ..patch_tree import AdaptiveCodedBTF
        from ..storage import load_coded, storage_report
        from ..storage.accounting import storage_summary
        from ..storage.adaptive_file import adaptive_report, attach_adaptive
        from ..storage.bundled import bundled_name, find_model
        from ..storage.coded_file import attach_model

        coded = load_coded(s, adaptive=True)
        adaptive = isinstance(coded, AdaptiveCodedBTF)
        model = None
        try:
            model = find_model(coded, model_path, s)  # type: ignore[arg-type]
            # the same checks as every reader, directions too
            (attach_adaptive if adaptive else attach_model)(coded, model, s)  # type: ignore[operator]
        except ModelMismatchError:
            if model_path:
                raise
            model = None  # storage figures from the file's own parameters
        report = (adaptive_report(coded, model, s) if adaptive  # type: ignore[arg-type]
                  else storage_report(coded, model, s))  # fmt: skip
        schema = _schema(s)
        tree = {} if not adaptive else {"tree": {
            "patch_sizes": list(coded.tree.sizes),  # type: ignore[union-attr]
            "nodes": {f"{p}x{p}": n for p, n in coded.tree.counts().items()},  # type: ignore[union-attr]
            "bytes_table4": report["bytes_tree"],
        }}  # fmt: skip
        return {
            "kind": "coded",
            "format": fmt,
            "name": coded.name,
            "shape": [coded.height, coded.width, len(coded.lights), len(coded.views), 3],
            "patch": coded.patch,
            **tree,
            "channels": list(coded.channels),
            "model_hash": coded.model_hash,
            "model": (f"bundled '{bundled_name(coded.model_hash)}'"
                      if bundled_name(coded.model_hash) else
                      (model.file or "given") if model is not None else
                      "not found (give -m MODEL.h5 for exact dictionary bytes)"),
            "params": coded.params,
            "dictionary_rule": _rule_text(coded),
            "objective": _objective_text(coded.objective),
            "preprocessing": {
                "standardisation": coded.stats.mode,
                "log_offset": coded.stats.log_offset,
                "bound": ("largest ln(RGB + offset) per angular image, every decoder clamps to it"
                          if coded.stats.bound is not None else
                          "none (older file: no clamp)" if schema < 3 else
                          "none (the file says its statistics have none, e.g. imported from "
                          "the release: no clamp)"),
            },
            "directions": {
                "lights": {"name": coded.lights.name, "count": len(coded.lights)},
                "views": {"name": coded.views.name, "count": len(coded.views)},
            },
            "schema_version": schema,
            **_highlights_info(coded, report),
            "nnz": report["nnz"],
            "storage": storage_summary(report),
            "integrity": _integrity(s),
        }
    return {"kind": "unknown", "format": fmt, "file_bytes": size}


def _highlights_info(coded: Any, report: dict[str, Any]) -> dict[str, Any]:
    """The highlight store, if the file has one: its entries, bytes and points using it."""
    h = getattr(coded, "highlight_store", None)  # an adaptive material has none
    if h is None:
        return {}
    used = int(np.count_nonzero(np.diff(h.offsets)))
    lobes = "none"
    if h.lobes is not None:
        lit = int(np.count_nonzero((h.lobes[..., 5:] > 0).any(axis=2)))
        lobes = f"{lit} of {h.lobes.shape[0] * h.lobes.shape[1]} texels lit"
    if h.tints is not None:
        code = "compact, tinted: an 8-bit float scale of each point's tint, Rice-coded nodes"
    elif h.compact:
        code = "compact: 8-bit float corrections, Rice-coded nodes"
    else:
        code = "binary16 corrections, 3-byte node keys"
    return {"highlights": {
        "entries": h.n_entries, "bytes_table4": report["bytes_highlights"], "code": code,
        "points_with_entries": f"{used} of {h.n_points}", "lobes": lobes,
        "meaning": "linear-RGB corrections at (texel, light, view) nodes and a glossy lobe "
                   "per texel, added by every decoder after the sparse code's value",
    }}  # fmt: skip


def _rule_text(coded: Any) -> str:
    """How the file's points chose their dictionary, in words."""
    rule, n = coded.dictionary_rule
    if rule == "screened":
        return (f"screened: the {n} best dictionaries by a partial projection coded exactly, "
                "the paper's rule among them")  # fmt: skip
    return "exhaustive: every dictionary coded exactly (the paper's rule)"


_OBJECTIVE_TEXT = {
    "log": "log: the standardised log-YUV error (the paper's rule)",
    "linear": "linear: each point's code judged by its error in linear RGB",
    "display": "display: each point's code judged by its error after the display mapping "
               "1.3*I^(1/1.8), clipped at 1",
}


def _objective_text(objective: str) -> str:
    """The error the file's codes minimise, in words."""
    return _OBJECTIVE_TEXT.get(objective, objective)


def _schema(path: str) -> int:
    from .._hdf5 import open_h5

    with open_h5(path) as f:
        return int(f.attrs["schema_version"])


def _integrity(path: str) -> str:
    """Which checksums protect the file (schema 2: fletcher32 on every dataset)."""
    from .._h5check import integrity
    from .._hdf5 import open_h5

    with open_h5(path) as f:
        return integrity(f)


def run(args: argparse.Namespace) -> int:
    info = describe(args.file, model_path=args.model, scan=not args.no_scan)
    if args.json:
        print_json(info)
    else:
        print(table(nested_rows(info)))
    return 0


def register(sub: Any) -> None:
    s = sub.add_parser("info", help="describe a BTF, model or coded file")
    s.add_argument("file", help="a .h5 file of ours (dense, model or coded), a UBO2014 .btf, a "
                   "UBO2003 .zip, or synth:CLASS[:SIZE[:SEED[:DIRECTIONS]]]")
    s.add_argument("-m", "--model",
                   help=MODEL_HELP + " (for a coded file; default: the one it names)")
    s.add_argument("--no-scan", action="store_true",
                   help="skip the value-range scan (it reads the whole BTF)")
    s.add_argument("--json", action="store_true", help="print one JSON object")
    s.set_defaults(func=run)
