"""Build the bundled ``release`` model from the authors' files, and measure its precision.

::

    python -m sparsebtf.storage.release_bundle RELEASE_DIR            # rebuild
    python -m sparsebtf.storage.release_bundle RELEASE_DIR --check    # compare only
    python -m sparsebtf.storage.release_bundle RELEASE_DIR --measure  # precision table

``RELEASE_DIR``: a folder with the files of the authors' GitHub release (docs/format.md §8).

The conversion: the fp64 ``DictEnsOrth4D{Y,U,V}.mat`` ensembles and ``bonn_angles.bin``
(:func:`~sparsebtf.storage.release.release_model`), every dictionary entry rounded to float32
(round to nearest even), τ_l = (256, 32, 32) from the paper's §4 (the release files do not
say it). It writes ``release.h5``, ``LICENSE-SparseBTF`` and ``PROVENANCE.md`` (source files
and their SHA-256) into ``sparsebtf/models/``.

Why float32 (``--measure``): the authors' coefficients (carpet07, felt05) decoded on float32
dictionaries stay within 0.0005 of a binary16 rounding step of their decoding on the fp64
originals; on the fp16 ``.bin`` dictionaries they move by up to ~4 steps. float32 costs half
the bytes of float64 in the wheel (4.0 MB against 7.9 MB; 3.7 MB since the file's datasets are
compressed losslessly).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import sys
from pathlib import Path

import numpy as np

from ..model import Model
from .bundled import models_dir
from .release import RELEASE, release_model

__all__ = [
    "SOURCE_FILES", "build", "compare_bundled", "measure_precision", "provenance_note",
    "release_bundle",
]  # fmt: skip

#: The release files the bundled model is made from, and the licence that travels with it.
SOURCE_FILES = (
    "DictEnsOrth4DY.mat", "DictEnsOrth4DU.mat", "DictEnsOrth4DV.mat", "bonn_angles.bin",
    "LICENSE-SparseBTF",
)  # fmt: skip
#: Training sparsity of the released ensembles: paper §4 ("τ_Y = 256, τ_U = 32, τ_V = 32").
TAU_TRAIN = {"Y": 256, "U": 32, "V": 32}
CONVERSION = (
    "DictEnsOrth4D{Y,U,V}.mat (fp64) read as DictDim1..4 (K = 8 matrices per mode, transposed "
    "to [k, row, col]); every entry rounded to float32 (round to nearest even); directions from "
    "bonn_angles.bin; standardisation 'shared' (the release's); tau_train from the paper's §4"
)


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def release_bundle(folder: str | Path) -> Model:
    """The bundled ``release`` model, converted afresh from the authors' files in ``folder``."""
    d = Path(folder)
    missing = [n for n in SOURCE_FILES if not (d / n).exists()]
    if missing:
        from ..errors import FileFormatError

        raise FileFormatError(f"{d}: missing {', '.join(missing)}")
    exact, _ = release_model(d, prefer="mat")
    rounded = {
        ch: [np.asarray(m, dtype=np.float32).astype(np.float64) for m in mats]
        for ch, mats in exact.dictionaries.items()
    }
    training = {ch: dict(t) for ch, t in exact.training.items()}
    return Model(
        rounded,
        exact.patch,
        exact.lights,
        exact.views,
        params={**exact.params, "tau_train": dict(TAU_TRAIN), "dictionary_dtype": "float32"},
        provenance={
            "name": "release",
            "source": f"the authors' SparseBTF release, {RELEASE}: ensembles trained on 18 "
            "UBO2014 materials (paper §4)",
            "release": RELEASE,
            "licence": "MIT, Copyright (c) 2023 Behnaz Kavoosighafi (LICENSE-SparseBTF beside "
            "this file)",
            "source_files": {n: sha256(d / n) for n in SOURCE_FILES},
            "conversion": CONVERSION,
            "tau_train_source": "paper §4: tau_Y = 256, tau_U = 32, tau_V = 32",
        },
        training=training,
    )


def provenance_note(model: Model) -> str:
    """``PROVENANCE.md`` for the bundled model (text derived from the model, so a rebuild
    gives the same note)."""
    p = model.provenance
    rows = "\n".join(f"| `{n}` | `{h}` |" for n, h in p["source_files"].items())
    counts = "\n".join(
        f"| {ch} | {model.training[ch].get('membership_counts')} | "
        f"{model.training[ch].get('seconds', 0):,.0f} |"
        for ch in model.channels
    )
    return f"""# Bundled model `release`: provenance

`release.h5` holds the SparseBTF authors' Y/U/V dictionary ensembles ({p['release']}):
K = 8 orthonormal 4D dictionaries per channel over 10×10 texels × 151 lights × 151 views
(the UBO2014 directions), trained on 18 measured UBO2014 materials (paper §4). Licence: MIT,
see `LICENSE-SparseBTF` in this folder (keep it with any copy).

Content hash: `{model.content_hash}`

Conversion: {p['conversion']}.
Rebuild and check with `python -m sparsebtf.storage.release_bundle FOLDER [--check]`, where
FOLDER holds these files (SHA-256):

| file | SHA-256 |
|---|---|
{rows}

Precision: the entries are stored in float32. Measured with
`python -m sparsebtf.storage.release_bundle FOLDER --measure`: the authors' carpet07/felt05
coefficients decoded on these dictionaries stay within 0.001 of a binary16 rounding step of
their decoding on the fp64 originals (at most 0.0005 step); on the fp16 `.bin` dictionaries
they move by up to 3.8 steps, and about half of the values land on another binary16 number.
Size: `release.h5` is 3.4 MB, its datasets stored with HDF5's lossless shuffle + deflate
filters (4.4 MB without them; the values are the same bit for bit). The wheel is 3.7 MB with
these float32 dictionaries (4.0 MB before the filters), 7.9 MB with the fp64 ones, 2.1 MB with
the fp16 ones and 0.25 MB without a model (`pip wheel --no-deps .`, measured once each).

Training record of the release (`.mat` variables `EnsHist`, `TrainTime`):

| channel | points per dictionary | seconds |
|---|---|---|
{counts}
"""


def build(folder: str | Path, out: str | Path | None = None) -> dict[str, Path]:
    """Write ``release.h5``, ``LICENSE-SparseBTF`` and ``PROVENANCE.md`` into ``out``
    (default: the package's ``models/`` folder)."""
    from .model_file import save_model

    d, o = Path(folder), Path(out) if out else models_dir()
    model = release_bundle(d)
    o.mkdir(parents=True, exist_ok=True)
    written = {"model": save_model(model, o / "release.h5")}
    shutil.copyfile(d / "LICENSE-SparseBTF", o / "LICENSE-SparseBTF")
    written["licence"] = o / "LICENSE-SparseBTF"
    (o / "PROVENANCE.md").write_text(provenance_note(model))
    written["provenance"] = o / "PROVENANCE.md"
    return written


def measure_precision(folder: str | Path, n_points: int = 8, seed: int = 0) -> list[dict]:
    """Decode the release's coefficients on fp16 / fp32 dictionaries vs the fp64 originals.

    For ``n_points`` random points of each material and channel, returns the largest
    difference in units of a binary16 rounding step (ulp) at the fp64-decoded value, and the
    share of values within half a step.
    """
    from ..learning.coding import reconstruct_points
    from .release import import_release

    d = Path(folder)
    exact, coded, _ = import_release(d, prefer="mat")
    half, _ = release_model(d, prefer="bin")
    single = release_bundle(d)
    rng = np.random.default_rng(seed)
    rows = []
    for name, c in coded.items():
        pts = np.sort(rng.choice(c.n_points, n_points, replace=False))
        for ch in c.channels:
            ref = reconstruct_points(c.codes[ch], exact.dictionaries[ch], pts, np.float64)
            step = np.spacing(np.abs(ref).astype(np.float16)).astype(np.float64)
            for label, m in (("float16 (.bin)", half), ("float32 (bundled)", single)):
                x = reconstruct_points(c.codes[ch], m.dictionaries[ch], pts, np.float64)
                err = np.abs(x - ref)
                rows.append({
                    "material": name, "channel": ch, "dictionaries": label,
                    "max_abs": float(err.max()), "max_ulp16": float((err / step).max()),
                    "within_half_ulp16": float(np.mean(err <= step / 2)),
                })  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m sparsebtf.storage.release_bundle",
        description="Build (or check) the bundled 'release' model from the authors' files.",
    )
    p.add_argument("folder", help="folder with the files of the authors' GitHub release "
                   "(DictEnsOrth4D*.mat, bonn_angles.bin, ...)")
    p.add_argument("--out", help="folder to write into (default: the package's models/)")
    p.add_argument("--check", action="store_true",
                   help="only compare the bundled files with a fresh conversion")
    p.add_argument("--measure", action="store_true",
                   help="print the decoding precision of fp16 and fp32 dictionaries")
    args = p.parse_args(argv)
    if args.measure:
        rows = measure_precision(args.folder)
        print(f"{'material':<10} {'ch':<3} {'dictionaries':<18} {'max |diff|':>11} "
              f"{'max ulp16':>10} {'<= ulp16/2':>11}")  # fmt: skip
        for r in rows:
            print(f"{r['material']:<10} {r['channel']:<3} {r['dictionaries']:<18} "
                  f"{r['max_abs']:>11.3g} {r['max_ulp16']:>10.4f} "
                  f"{r['within_half_ulp16']:>10.2%}")  # fmt: skip
        return 0
    if args.check:
        problems = compare_bundled(args.folder)
        print("\n".join(problems) or "the bundled model equals a fresh conversion")
        return 1 if problems else 0
    for what, path in build(args.folder, args.out).items():
        print(f"wrote {path} ({what})")
    return 0


def compare_bundled(folder: str | Path) -> list[str]:
    """Differences between the bundled files and a fresh conversion of ``folder`` (empty when
    they agree): dictionaries bit for bit, hash, directions, metadata, licence, note."""
    from .bundled import load_bundled

    fresh = release_bundle(folder)
    have = load_bundled("release")
    out = []
    if have.content_hash != fresh.content_hash:
        out.append(f"content hash {have.content_hash[:12]} != fresh {fresh.content_hash[:12]}")
    if not (have.lights.equals(fresh.lights, 0) and have.views.equals(fresh.views, 0)):
        out.append("direction tables differ")
    for field in ("params", "provenance", "training"):
        a = json.loads(json.dumps(getattr(have, field), default=str))
        b = json.loads(json.dumps(getattr(fresh, field), default=str))
        if a != b:
            out.append(f"{field} differ: {a} != {b}")
    lic = models_dir() / "LICENSE-SparseBTF"
    if not lic.exists() or lic.read_bytes() != (Path(folder) / "LICENSE-SparseBTF").read_bytes():
        out.append(f"{lic} is missing or differs from the release's")
    note = models_dir() / "PROVENANCE.md"
    if not note.exists() or note.read_text() != provenance_note(fresh):
        out.append(f"{note} is missing or differs from a fresh one")
    return out


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
