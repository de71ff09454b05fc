"""``sparsebtf models``: the models bundled with the package (name, hash, geometry, source)."""

from __future__ import annotations

import argparse
from typing import Any

from ._output import print_json, table

__all__ = ["register"]


def run(args: argparse.Namespace) -> int:
    from ..storage.bundled import DEFAULT_MODEL, bundled_models

    described = [m.describe() for m in bundled_models().values()]
    if args.json:
        print_json({"default": DEFAULT_MODEL, "models": described})
        return 0
    if not described:
        print("no bundled models in this installation (sparsebtf/models/*.h5 is missing)")
        return 0
    for d in described:
        tau = d["tau_train"]
        k = d["n_dictionaries"]
        print(table([
            ("name", d["name"] + (" (the default of 'sparsebtf encode')"
                                  if d["name"] == DEFAULT_MODEL else "")),
            ("content hash", d["content_hash"]),
            ("channels", ", ".join(f"{ch} (K = {k[ch]})" for ch in d["channels"])),
            ("data point", " x ".join(map(str, d["mode_sizes"]))
             + f" (patch {d['patch']}x{d['patch']} texels x lights x views)"),
            ("directions", f"{d['directions']['lights']['count']} lights x "
             f"{d['directions']['views']['count']} views ({d['directions']['lights']['name']})"),
            ("tau_l", ",".join(str(tau[ch]) for ch in d["channels"]) if tau else "unknown"),
            ("source", d["source"]),
            ("licence", d["licence"]),
            ("file", f"{d['file']} ({d['file_bytes'] / 2**20:.1f} MiB)"),
        ]))  # fmt: skip
        print()
    return 0


def register(sub: Any) -> None:
    s = sub.add_parser("models", help="list the models bundled with sparsebtf",
                       description="List the bundled models: use one by name with "
                       "'sparsebtf encode BTF -m NAME'; coded files find them by hash.")
    s.add_argument("--json", action="store_true", help="print one JSON object")
    s.set_defaults(func=run)
