"""``sparsebtf lookup``: one BTF value in every domain, for checking a shader against ours.

For texel (row, col) (the release's convention: ``point = row//p + (H/p)·(col//p)``), light
index l and view index v, reports per channel the ``standardized`` value (Eq. 5 on the codes),
the ``log`` value (x·σ + μ, the log-YUV domain) and ``rgb`` (exp(min(YUV⁻¹·log, bound)) − offset,
the material's log offset and bound, as every decoder), or null
when a channel is missing (the release ships no Y coefficients; ``rgb_note`` says so).
"""

from __future__ import annotations

import argparse
import os
from typing import Any

import numpy as np

from ..colour import yuv_to_rgb
from ..errors import BTFInputError, SparseBTFError
from ..open import file_format, open_btf
from ..points.grid import PatchGrid
from ..points.preprocessing import inverse_log_transform, to_log_yuv
from ..points.statistics import gather_statistics
from ._args import integer
from ._model import MODEL_HELP
from ._output import add_allow_nonfinite, check_finite_result, format_value, print_json, table

__all__ = ["lookup", "register"]


def _check(r: int, c: int, light: int, view: int, shape: tuple[int, ...]) -> None:
    h, w, nl, nv = shape[:4]
    for name, val, n in (("--texel row", r, h), ("--texel column", c, w),
                         ("--light", light, nl), ("--view", view, nv)):  # fmt: skip
        if not 0 <= val < n:
            raise BTFInputError(f"{name} {val} is out of range [0, {n}) (0-based)")


def lookup(
    path: str | os.PathLike[str],
    row: int,
    col: int,
    light: int,
    view: int,
    model_path: str | None = None,
) -> dict[str, Any]:
    """The value at (row, col, light, view) of a coded or dense file, in every domain."""
    s = str(path)
    fmt = "btf" if s.startswith("synth:") or s.lower().endswith((".btf", ".zip")) else (
        file_format(path))  # fmt: skip
    out: dict[str, Any] = {"texel": [row, col], "light": light, "view": view}
    if fmt == "sparsebtf-coded":
        from ..patch_tree import AdaptiveCodedBTF
        from ..runtime import decode_points_eq5
        from ..storage import load_coded_with_model

        coded = load_coded_with_model(path, model_path, adaptive=True)
        _check(
            row, col, light, view, (coded.height, coded.width, len(coded.lights), len(coded.views))
        )
        if isinstance(coded, AdaptiveCodedBTF):  # the layer of the node covering the texel
            size = int(coded.tree.sizes_at(np.array(row), np.array(col)))
            out["node_size"] = size
            coded = coded.layers[size]
        grid = PatchGrid(coded.height, coded.width, coded.patch)
        p, i1, i2 = (int(v) for v in grid.locate(row, col))
        mu, sd = coded.stats.select([light], [view])
        std, log = {}, {}
        for ch_i, ch in enumerate(coded.channels):
            z = decode_points_eq5(coded, ch, [p], [light], [view])[0, i1, i2, 0, 0]
            c = min(ch_i, mu.shape[2] - 1)
            std[ch] = float(z)
            log[ch] = float(z * sd[0, 0, c] + mu[0, 0, c])
        out.update(point=p, in_patch=[i1, i2], standardized=std, log=log)
        if all(ch in log for ch in ("Y", "U", "V")):
            log_rgb = yuv_to_rgb(np.array([[[log["Y"], log["U"], log["V"]]]]))
            coded.stats.clamp_log_rgb(log_rgb, [light], [view])  # as every decoder does
            rgb = inverse_log_transform(log_rgb, coded.stats.log_offset)[0, 0]
            out["rgb"] = [float(v) for v in rgb]
        else:
            missing = [ch for ch in ("Y", "U", "V") if ch not in log]
            out["rgb"] = None
            out["rgb_note"] = (
                f"null: RGB needs Y, U and V, and this file codes no {', '.join(missing)}"
                + (" (the authors' release ships no Y coefficients)"
                   if coded.params.get("source") == "release" else "")
            )  # fmt: skip
        return out
    btf = open_btf(path, model_path)
    _check(row, col, light, view, btf.shape)
    rgb = btf.read([row], [col], [light], [view])[0, 0, 0, 0].astype(np.float64)
    logv = to_log_yuv(np.maximum(rgb, 0))
    stats = gather_statistics(btf, "shared", progress=False)
    mu, sd = stats.select([light], [view])
    out.update(
        standardized={
            ch: float((logv[i] - mu[0, 0, 0]) / sd[0, 0, 0]) for i, ch in enumerate("YUV")
        },
        log={ch: float(logv[i]) for i, ch in enumerate("YUV")},
        rgb=[float(v) for v in rgb],
    )
    return out


def run(args: argparse.Namespace) -> int:
    try:
        r, c = (int(v) for v in args.texel.split(","))
    except ValueError:
        raise SparseBTFError(f"--texel must look like R,C, got {args.texel!r}") from None
    out = lookup(args.file, r, c, args.light, args.view, model_path=args.model)
    check_finite_result(out, "lookup", args.allow_nonfinite)
    if args.json:
        print_json(out)
    else:
        print(lookup_table(out))
    return 0


def lookup_table(out: dict[str, Any]) -> str:
    """:func:`lookup`'s result for people: where, then one row per domain, one column per
    channel (``-`` for a channel the file does not code)."""
    where = [("texel (row, col)", format_value(out["texel"])),
             ("light, view (indices)", f"{out['light']}, {out['view']}")]  # fmt: skip
    if "node_size" in out:
        where.append(("node (adaptive patch sizes)", f"{out['node_size']}x{out['node_size']}"))
    if "point" in out:
        where.append(("data point", f"{out['point']} (texel {format_value(out['in_patch'])} "
                                    "of its patch)"))  # fmt: skip
    channels = ("Y", "U", "V")

    def cells(values: dict[str, float] | list[float] | None) -> list[str]:
        if values is None:
            return ["-"] * 3
        if isinstance(values, dict):
            return [f"{values[ch]:.6g}" if ch in values else "-" for ch in channels]
        return [f"{v:.6g}" for v in values]

    grid = [("", ["Y", "U", "V"]),
            ("standardised (Eq. 5)", cells(out.get("standardized"))),
            ("log-YUV", cells(out.get("log"))),
            ("", ["R", "G", "B"]),
            ("linear RGB", cells(out.get("rgb")))]  # fmt: skip
    lines = [table(where)]
    width = max(len(k) for k, _ in grid)
    cols = [max(len(row[1][i]) for row in grid) for i in range(3)]
    for k, vals in grid:
        lines.append(f"{k:<{width}}  " + "  ".join(f"{v:>{w}}" for v, w in zip(vals, cols,
                                                                                   strict=True)))
    if out.get("rgb_note"):
        lines.append(f"(no linear RGB: {out['rgb_note'].removeprefix('null: ')})")
    return "\n".join(lines)


def register(sub: Any) -> None:
    s = sub.add_parser("lookup", help="one value of a coded or dense BTF, in every domain")
    s.add_argument("file", help="coded or dense .h5 file (or .btf, .zip, synth:...)")
    s.add_argument("--texel", required=True,
                   help="R,C: row and column, 0-based (the release's convention)")
    s.add_argument("--light", type=int, required=True, help="light index, 0-based")
    s.add_argument("--view", type=int, required=True, help="view index, 0-based")
    s.add_argument("-m", "--model", help=MODEL_HELP + " (default: the one the coded file names)")
    s.add_argument("--json", action="store_true", help="print one JSON object")
    add_allow_nonfinite(s)
    s.set_defaults(func=run, checks={"light": integer(0), "view": integer(0)})
