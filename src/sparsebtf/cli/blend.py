"""``sparsebtf blend``: inter-BTF interpolation in coefficient space (§3.5, Eq. 7–9).

    sparsebtf blend A.h5 B.h5 --alpha 0.3 -o C.h5
    sparsebtf blend A.h5 B.h5 --sweep 11 --png DIR      # Figure 6: a strip from α = 0 to 1
    sparsebtf blend A.h5 B.h5 C.h5 --weights 0.2,0.3,0.5 -o D.h5
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import BTFInputError
from ..runtime.angular import SCHEMES
from ._args import (
    add_deprecated_alias,
    check_output_dir,
    check_output_file,
    check_tau,
    integer,
    number,
)
from ._output import format_value, print_json

__all__ = ["register"]

# Figure 6 of the paper: incident azimuth/elevation 270°, 66.5°; observation 15°, 79°.
FIGURE6_LIGHT = "270,66.5"
FIGURE6_VIEW = "15,79"


def direction(text: str, what: str) -> np.ndarray:
    """"azimuth,elevation" in degrees → a unit vector of the local frame (z = normal)."""
    try:
        az, el = (np.radians(float(t)) for t in text.split(","))
    except ValueError:
        raise BTFInputError(
            f"{what} must be 'azimuth,elevation' in degrees, got {text!r}"
        ) from None
    if not np.isfinite(az):
        raise BTFInputError(f"{what}: azimuth must be a finite number of degrees, got {text!r}")
    if not 0 < el <= np.pi / 2 + 1e-12:
        raise BTFInputError(f"{what}: elevation must be in (0, 90] degrees, got {np.degrees(el)}")
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def _weights(args: argparse.Namespace, n: int) -> list[float]:
    if args.weights is not None:
        try:
            w = [float(t) for t in args.weights.split(",")]
        except ValueError:
            raise BTFInputError(
                f"--weights must be numbers separated by commas: {args.weights!r}"
            ) from None
        if not all(np.isfinite(w)):
            raise BTFInputError(f"--weights must be finite numbers, got {args.weights!r}")
        if len(w) != n:
            raise BTFInputError(f"--weights gives {len(w)} weights for {n} inputs")
        return w
    if args.alpha is None:
        if args.sweep:
            return []
        raise BTFInputError("give --alpha (two inputs), --weights or --sweep")
    if n != 2:
        raise BTFInputError(f"--alpha blends two inputs, got {n}; use --weights")
    if not 0 <= args.alpha <= 1:
        raise BTFInputError(f"--alpha must be in [0, 1], got {args.alpha}")
    return [1 - args.alpha, args.alpha]


def alpha_strip(tiles: list[np.ndarray], alphas: list[float], path: Path) -> Path:
    """The sweep's images side by side, each labelled with its α (Figure 6 style)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from ..figures import save_figure

    h, w = tiles[0].shape[:2]
    scale = max(1.0, 96 / max(h, w))
    fig, axes = plt.subplots(1, len(tiles), squeeze=False,
                             figsize=(len(tiles) * (w * scale / 100 + 0.1), h * scale / 100 + 0.4))
    for ax, tile, a in zip(axes[0], tiles, alphas, strict=True):
        ax.imshow(tile, interpolation="nearest")
        ax.set_title(f"α = {a:.2f}", fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
    return save_figure(fig, path, dpi=100)


def cmd_blend(args: argparse.Namespace) -> int:
    from ..display import tone_map
    from ..figures import save_png
    from ..patch_tree import AdaptiveCodedBTF
    from ..runtime import AdaptiveRuntimeBTF, RuntimeBTF, blend
    from ..storage import load_coded_with_model, save_coded

    if len(args.inputs) < 2:
        raise BTFInputError("blend needs at least two coded files")
    weights = _weights(args, len(args.inputs))
    tau = check_tau(args.tau)
    if weights and not args.output:
        raise BTFInputError("give -o OUT.h5 for the blended coded file")
    if args.sweep and not args.png:
        raise BTFInputError("--sweep needs --png DIR for the strip of renders")
    if args.sweep and len(args.inputs) != 2:
        raise BTFInputError("--sweep runs α from 0 to 1 between two inputs")
    check_output_file(args.output, [*args.inputs, args.model], kind="coded")
    check_output_dir(args.png, "--png")
    coded = [load_coded_with_model(p, args.model, adaptive=True) for p in args.inputs]
    report: dict[str, Any] = {"inputs": [str(p) for p in args.inputs]}
    if weights:
        out = blend(coded, weights=weights, tau=tau)
        out.params["model_file"] = coded[0].model_file
        save_coded(out, args.output)
        report.update(output=str(args.output), weights=weights, nnz=out.nnz())
    if args.sweep:
        if args.sweep < 2:
            raise BTFInputError(f"--sweep needs at least 2 steps, got {args.sweep}")
        light = direction(args.light_dir, "--light-dir")
        view = direction(args.view_dir, "--view-dir")
        folder = Path(args.png)
        folder.mkdir(parents=True, exist_ok=True)
        tiles, frames = [], []
        for alpha in np.linspace(0.0, 1.0, args.sweep):
            mixed = blend(coded, alpha=float(alpha), tau=tau, progress=False)
            rt = (AdaptiveRuntimeBTF(mixed) if isinstance(mixed, AdaptiveCodedBTF)
                  else RuntimeBTF(mixed))  # fmt: skip
            img = rt.image(light, view, interpolation=args.interpolation)
            tile = tone_map(img)
            path = save_png(folder / f"blend_alpha_{alpha:.2f}.png", tile)
            tiles.append(tile)
            frames.append({"alpha": float(alpha), "png": str(path),
                           "mean_rgb": img.reshape(-1, 3).mean(axis=0).tolist()})  # fmt: skip
        report["strip"] = str(alpha_strip(tiles, [f["alpha"] for f in frames],
                                          folder / "blend_strip.png"))  # fmt: skip
        report["sweep"] = frames
    if args.json:
        print_json(report)
    else:
        if "output" in report:
            print(f"wrote {report['output']}: weights {format_value(weights)}, coefficients "
                  f"{format_value(report['nnz'])}")
        if "strip" in report:
            print(f"wrote {report['strip']} ({args.sweep} renders, α = 0 … 1)")
    return 0


def register(sub: Any) -> None:
    s = sub.add_parser(
        "blend",
        help="blend coded BTFs in coefficient space (Eq. 7-9); --sweep renders a strip",
        description="Blend coded BTFs of one model in coefficient space (paper §3.5, "
        "Eq. 7-9): a new material between them, or with --sweep a strip of renders from α = 0 "
        "(the first input) to 1 (the second), labelled with α. Materials coded with adaptive "
        "patch sizes blend on the common refinement of their trees.",
        epilog="examples:\n"
        "  sparsebtf blend A.coded.h5 B.coded.h5 --alpha 0.3 -o mix.h5\n"
        "  sparsebtf blend A.coded.h5 B.coded.h5 --sweep 11 --png strip/   # Figure 6\n"
        "  sparsebtf blend A.h5 B.h5 C.h5 --weights 0.2,0.3,0.5 -o D.h5",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    s.add_argument("inputs", nargs="+", metavar="CODED",
                   help="coded files of one model (.h5), at least two")
    s.add_argument("--alpha", type=float, help="weight of the second input (Eq. 7), in [0, 1]")
    s.add_argument("--weights", help="one weight per input, comma separated, summing to 1")
    s.add_argument("-o", "--output", help="blended coded file to write")
    s.add_argument("--tau", help="sparsity of the result per channel (default: the inputs')")
    s.add_argument("-m", "--model",
                   help="model file or bundled model name (default: the one the coded files "
                   "name)")
    s.add_argument("--sweep", type=int, default=0, help="render N blends from α = 0 to 1")
    s.add_argument("--png", help="folder for the sweep's PNGs (blend_strip.png and one per α)")
    s.add_argument("--light-dir", default=FIGURE6_LIGHT, metavar="AZ,EL",
                   help=f"light direction 'azimuth,elevation' in degrees (default "
                   f"{FIGURE6_LIGHT})")
    s.add_argument("--view-dir", default=FIGURE6_VIEW, metavar="AZ,EL",
                   help=f"view direction 'azimuth,elevation' in degrees (default {FIGURE6_VIEW})")
    for what in ("light", "view"):
        add_deprecated_alias(s, f"--{what}", f"--{what}-dir",
                             f"in 'blend' it meant degrees; 'lookup --{what}' is an index")
    s.add_argument("--interpolation", default="linear", choices=SCHEMES,
                   help="angular interpolation of the sweep's renders (default linear)")
    s.add_argument("--json", action="store_true", help="print the result as JSON")
    s.set_defaults(func=cmd_blend, checks={
        "alpha": number(0, 1, unit="(weight of the second input)"),
        "sweep": integer(0, 10**4, unit="renders"),
    })  # fmt: skip
