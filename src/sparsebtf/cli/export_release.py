"""``sparsebtf export-release``: a coded file in the authors' release layout (coefficients,
statistics, directions), for their OptiX renderer; ``import-release`` reads it back."""

from __future__ import annotations

import argparse
from typing import Any

from ._args import check_output_dir, output_format
from ._output import print_json

__all__ = ["register"]


def run(args: argparse.Namespace) -> int:
    from ..storage import load_coded
    from ..storage.bundled import bundled_models
    from ..storage.release_write import check_name, export_release

    check_name(args.name, "--name")
    output_format(args.coded, "coded", "CODED")
    check_output_dir(args.folder, "OUT")
    coded = load_coded(args.coded)
    release_hash = bundled_models()["release"].content_hash
    written = export_release(coded, args.folder, release_hash, name=args.name)
    tau = {ch: int(c.counts.max()) if c.counts.size else 0 for ch, c in coded.codes.items()}
    size = "" if (coded.height, coded.width) == (400, 400) else \
        f" --size {coded.height}x{coded.width}"  # fmt: skip
    again = f"sparsebtf import-release {args.folder} -m release{size}"
    if args.json:
        print_json({"written": [str(p) for p in written], "most_coefficients_per_point": tau,
                    "constant_count": {ch: bool((c.counts == c.counts[0]).all())
                                       for ch, c in coded.codes.items()},
                    "clamp_bound_dropped": coded.stats.bound is not None,
                    "import_with": again})  # fmt: skip
        return 0
    for p in written:
        print(f"wrote {p}")
    print("most coefficients in a point: " + ", ".join(f"{ch} {n}" for ch, n in tau.items()))
    varying = [ch for ch, c in coded.codes.items() if not (c.counts == c.counts[0]).all()]
    if varying:
        print(
            f"note: channels {', '.join(varying)} keep a varying count per point; the authors' "
            "renderer reads a constant count (its sparsity argument)"
        )
    if coded.stats.bound is not None:
        print("note: the release layout holds no clamp bound; its decoders (import-release, the "
              "authors' renderer) do not clamp where this file's decode does")
    print(f"read back with: {again}")
    return 0


def register(sub: Any) -> None:
    s = sub.add_parser(
        "export-release",
        help="a coded file in the authors' release layout (their renderer's input)",
    )
    s.add_argument("coded", help="coded file (.h5) coded on the bundled 'release' model")
    s.add_argument(
        "folder",
        help="folder to write Coeffs_BTF_*.bin, *_mean_std.bin, "
        "bonn_angles.bin, xyz_loc.bin into (no dictionaries: the release's are used)",
    )
    s.add_argument("--name", help="material name in the file names, not empty (default: the coded "
                   "file's)")
    s.add_argument("--json", action="store_true", help="print what was written as JSON")
    s.set_defaults(func=run)
