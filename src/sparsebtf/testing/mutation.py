"""Hostile inputs for every reader: seeded byte-level mutations of the corpus's files
(:mod:`sparsebtf.testing.corpus`) and the operation each reader's user runs. Used by
``tests/test_fuzz.py`` (a few hundred cases per reader, in process) and ``benchmarks/fuzz.py``
(thousands, each in a subprocess with a memory cap and a time limit).

A reader passes a case when it either accepts the mutated file or raises a
:class:`~sparsebtf.errors.SparseBTFError`; any other exception, a crash, a hang or a memory
blow-up is a defect. Every case is a pure function of ``(reader, seed)``, so a failure found by
the benchmark is replayed with :func:`run_case`.
"""

from __future__ import annotations

import io
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from ..formats.registry import fuzz_readers

__all__ = ["READERS", "exercise", "mutate", "run_case", "sizes", "write_case"]

#: The readers fuzzed, in report order: the registered formats that have a corpus maker.
READERS = fuzz_readers()

#: Interesting 32-bit words for size and count fields.
_WORDS = (0, 1, 2, 3, 0x7F, 0xFF, 0x7FFF, 0xFFFF, 0x10000, 0x7FFFFFFF, 0x80000000, 0x80000003,
          0xFFFFFFFE, 0xFFFFFFFF)  # fmt: skip


# --------------------------------------------------------------------------- mutations


def mutate(data: bytes, rng: np.random.Generator) -> bytes:
    """One to three random edits: bit flips, byte and word overwrites with boundary values,
    truncation, deletion, duplication or insertion of a span."""
    b = bytearray(data)
    for _ in range(int(rng.integers(1, 4))):
        n = len(b)
        op = int(rng.integers(9)) if n else 8
        pos = int(rng.integers(n)) if n else 0
        if op <= 2:  # the most common damage: flipped bits
            for _ in range(int(rng.integers(1, 9))):
                i = int(rng.integers(n))
                b[i] ^= 1 << int(rng.integers(8))
        elif op == 3:
            b[pos] = int(rng.choice([0x00, 0x01, 0x7F, 0x80, 0xFF, int(rng.integers(256))]))
        elif op in (4, 5):  # a size or count field: an aligned little-endian word
            width = 8 if op == 5 else 4
            pos -= pos % width
            word = int(rng.choice(_WORDS)) if op == 4 else int(rng.choice(_WORDS)) << 16
            b[pos : pos + width] = word.to_bytes(8, "little")[:width][: max(0, n - pos)]
        elif op == 6:
            del b[int(rng.integers(n)) :]
        elif op == 7:
            span = int(rng.integers(1, min(n, 512) + 1))
            chunk = bytes(b[pos : pos + span])
            if rng.integers(2):
                del b[pos : pos + span]
            else:
                b[pos:pos] = chunk
        else:
            b[pos:pos] = rng.integers(0, 256, int(rng.integers(1, 64)), dtype=np.uint8).tobytes()
    return bytes(b)


def _mutate_member(data: bytes, rng: np.random.Generator) -> bytes:
    """The archive ``data`` rewritten with one member mutated (its CRC recomputed)."""
    out = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(data)) as zi:
        infos = zi.infolist()
        victim = int(rng.integers(len(infos)))
        with zipfile.ZipFile(out, "w", infos[0].compress_type) as zo:
            for i, info in enumerate(infos):
                blob = zi.read(info)
                zo.writestr(info.filename, mutate(blob, rng) if i == victim else blob)
    return out.getvalue()


def write_case(corpus: dict[str, list[Path]], reader: str, seed: int, folder: Path) -> Path:
    """Write case ``seed`` of ``reader`` (a mutated copy of one corpus file) into ``folder``."""
    rng = np.random.default_rng([READERS.index(reader), seed])
    files = corpus[reader]
    src = files[int(rng.integers(len(files)))]
    target = folder / src.name
    folder.mkdir(parents=True, exist_ok=True)
    tmp = target.with_suffix(target.suffix + ".tmp")
    if src.suffix == ".zip" and rng.integers(2):
        # Half the zip cases damage one image inside a valid archive (correct CRCs), so the
        # JPEG and Radiance parsers are reached, not only the archive's own checks.
        tmp.write_bytes(_mutate_member(src.read_bytes(), rng))
    else:
        tmp.write_bytes(mutate(src.read_bytes(), rng))
    os.replace(tmp, target)
    return target


# --------------------------------------------------------------------------- what users run


def _scan(btf: Any) -> None:
    for block in btf.iter_blocks():
        np.isfinite(block).sum()


def exercise(reader: str, path: Path, corpus_dir: Path) -> None:
    """What a user of ``reader`` runs on ``path``: ``sparsebtf info`` (value scan included),
    plus a full decode for coded files; the release readers at the corpus geometry."""
    from ..cli.info import describe

    if reader in ("ubo2014", "ubo2003", "dense", "model"):
        describe(path)
    elif reader == "coded":
        from ..runtime import RuntimeBTF, coded_btf_view
        from ..storage import load_coded_with_model

        describe(path, model_path=str(corpus_dir / "model.h5"))
        coded = load_coded_with_model(path, corpus_dir / "model.h5")
        _scan(coded_btf_view(coded))
        RuntimeBTF(coded, tau=0.5).arrays(neighbours=False)  # what the viewer and the renderer load
    elif reader == "release":
        _release(path)
    else:  # pragma: no cover
        raise ValueError(reader)


def _release(path: Path) -> None:
    from ..storage import release

    sizes = (2, 2, 3, 2)
    name = path.name
    if name.startswith("DictEnsOrth4D"):
        release.read_dictionaries(path, 2, sizes)
    elif name.startswith("Coeffs_BTF_"):
        release.read_coefficients(path, n_points=4, n_dictionaries=2)
    elif name.endswith("_mean_std.bin"):
        release.read_mean_std(path, 3, 2)
    else:
        release.read_angles(path)


def run_case(
    corpus: dict[str, list[Path]], reader: str, seed: int, folder: Path, corpus_dir: Path
) -> str:
    """Run one case in this process: ``"accepted"`` or ``"error"`` (a clean project error);
    anything else propagates (a defect)."""
    from ..errors import SparseBTFError

    path = write_case(corpus, reader, seed, folder)
    try:
        exercise(reader, path, corpus_dir)
    except SparseBTFError:
        return "error"
    return "accepted"


def sizes(corpus: dict[str, list[Path]]) -> dict[str, int]:
    """The largest seed file per reader (mutations add at most a few hundred bytes)."""
    return {r: max(p.stat().st_size for p in files) for r, files in corpus.items()}
