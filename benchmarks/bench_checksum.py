"""What the schema-2 integrity checks cost: fletcher32 on every dataset, HDF5 1.10 structures
(checksummed metadata) and the watchdog walk of each new input, on a 400×400 coded file.

The coded file is UBO2014-size (400×400 texels, 151×151 directions, K = 8, τ = 885,64,64:
1.62 M coefficients). The same codes are written three ways and loaded with ``load_coded``:

* schema 2 (ours): HDF5 1.10 structures, fletcher32 on every dataset;
* the same without fletcher32 (isolates the data checksums);
* schema 1's layout (HDF5's earliest structures, contiguous datasets, variable-length
  strings, no checksum: what files written before schema 2 look like).

The alternative the issue names, a stored content hash checked on load, is timed as SHA-256
over the same dataset bytes. A dense file (``--dense-size`` texels, 151×151 directions) is
scanned (``info``'s chunk-aligned scan, and the encoder's view-by-view statistics pass) with
and without fletcher32 to show the cost on large reads. All ratios are measured
in one run, the variants' runs interleaved.

    python benchmarks/bench_checksum.py [--dense-size 20] [--json]
"""

from __future__ import annotations

import argparse
import hashlib
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import h5py

from _common import best_of, machine, report, synthetic_coded
from sparsebtf._hdf5 import _probe
from sparsebtf.data.dense_file import DenseFileBTF, write_dense
from sparsebtf.fuzzing import _legacy_copy
from sparsebtf.points.statistics import gather_statistics
from sparsebtf.storage import load_coded, save_coded


def _rewrite(src: Path, dst: Path, libver: str | tuple[str, str], fletcher32: bool) -> Path:
    """``src`` with every dataset rewritten (same values) under other storage settings."""
    with h5py.File(src, "r") as fi, h5py.File(dst, "w", libver=libver) as fo:
        for k, v in fi.attrs.items():
            fo.attrs[k] = v

        def copy(name: str, obj: object) -> None:
            if isinstance(obj, h5py.Group):
                g = fo.create_group(name)
                for k, v in obj.attrs.items():
                    g.attrs[k] = v
            else:
                assert isinstance(obj, h5py.Dataset)
                data = obj[()]
                kw = {"chunks": obj.chunks} if obj.chunks and data.size else {}
                if fletcher32 and data.size:
                    kw["fletcher32"] = True
                d = fo.create_dataset(name, data=data, **kw)
                for k, v in obj.attrs.items():
                    d.attrs[k] = v

        fi.visititems(copy)
    return dst


def interleaved_best(fns: dict[str, Callable[[], object]], repeat: int) -> dict[str, float]:
    """Best wall time of each function, the runs interleaved (A, B, C, A, B, C, …) so that
    a change in the machine's load hits every variant alike; one warm-up run each."""
    best = dict.fromkeys(fns, float("inf"))
    for r in range(repeat + 1):
        for name, fn in fns.items():
            t = time.perf_counter()
            fn()
            if r:
                best[name] = min(best[name], time.perf_counter() - t)
    return best


def _sha256_of_datasets(path: Path) -> str:
    h = hashlib.sha256()
    with h5py.File(path, "r") as f:
        f.visititems(lambda n, o: h.update(o[()].tobytes()) if isinstance(o, h5py.Dataset)
                     else None)  # fmt: skip
    return h.hexdigest()


def _stats(path: Path, cache: int | None = None) -> None:
    """The encoder's statistics pass: one view block at a time (not chunk-aligned); ``cache``
    replaces the default chunk cache (an eighth of the memory budget)."""
    DenseFileBTF.chunk_cache = cache
    try:
        with DenseFileBTF(path) as btf:
            gather_statistics(btf, progress=False)
    finally:
        DenseFileBTF.chunk_cache = None


def _scan(path: Path) -> None:
    with DenseFileBTF(path) as btf:
        for block in btf.iter_blocks():
            block.sum()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--size", type=int, default=400, help="coded texels per side (default 400)")
    p.add_argument("--dense-size", type=int, default=20, help="dense texels per side (default 20)")
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--json", action="store_true")
    args = p.parse_args()

    coded = synthetic_coded(size=args.size)
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        ours = save_coded(coded, d / "schema2.h5", schema=2)
        t_write = best_of(lambda: save_coded(coded, d / "w.h5", schema=2), 3)
        plain = _rewrite(ours, d / "nofletcher.h5", ("v110", "v110"), fletcher32=False)
        old = _legacy_copy(ours, d / "schema1.h5")
        with h5py.File(plain, "a") as f:  # read like a schema-1 file
            f.attrs["schema_version"] = 1
        files = {"schema 2": ours, "no fletcher32": plain, "schema 1": old}
        for path in files.values():
            load_coded(path)  # the watchdog walks each file once; later loads skip it
        times = interleaved_best(
            {**{n: (lambda p=p: load_coded(p)) for n, p in files.items()},
             "walk": lambda: _probe(ours), "sha": lambda: _sha256_of_datasets(plain)},
            args.repeat,
        )  # fmt: skip
        loads = {n: times[n] for n in files}
        walk, sha = times["walk"], times["sha"]
        sizes = {n: p.stat().st_size for n, p in (("schema 2", ours), ("no fletcher32", plain),
                                                  ("schema 1", old))}  # fmt: skip

        dense = None
        if args.dense_size:
            from sparsebtf.data.synth import synthesize

            btf = synthesize("stone", args.dense_size, "ubo2014", 0)
            dense = write_dense(d / "dense.h5", btf)
            plain_dense = _rewrite(dense, d / "dense_plain.h5", ("v110", "v110"), False)
            scans = interleaved_best({"fletcher32": lambda: _scan(dense),
                                      "plain": lambda: _scan(plain_dense),
                                      "stats": lambda: _stats(dense),
                                      "stats_plain": lambda: _stats(plain_dense),
                                      "stats_1mib": lambda: _stats(dense, 2**20),
                                      "stats_plain_1mib": lambda: _stats(plain_dense, 2**20)},
                                     3)  # fmt: skip
            t_dense, t_plain = scans["fletcher32"], scans["plain"]

    nnz = coded.nnz()
    rows = [
        ("coded file", f"{args.size}x{args.size}, K = 8, nnz {nnz}, {sizes['schema 2'] / 2**20:.2f}"
                       " MiB (schema 2)"),
        ("load_coded, schema 2", f"{loads['schema 2'] * 1000:.1f} ms"),
        ("load_coded, no fletcher32", f"{loads['no fletcher32'] * 1000:.1f} ms"),
        ("load_coded, schema-1 layout", f"{loads['schema 1'] * 1000:.1f} ms"),
        ("fletcher32 cost on load", f"{loads['schema 2'] / loads['no fletcher32']:.2f}x"),
        ("schema 2 vs schema-1 layout", f"{loads['schema 2'] / loads['schema 1']:.2f}x"),
        ("watchdog walk (first open only)", f"{walk * 1000:.1f} ms "
                                            f"({walk / loads['schema 2']:.2f}x a load)"),
        ("SHA-256 of all datasets (the alternative)",
         f"{sha * 1000:.1f} ms ({sha / loads['no fletcher32']:.2f}x a load)"),
        ("save_coded, schema 2", f"{t_write * 1000:.1f} ms"),
        ("file size, schema 2 / schema-1 layout", f"{sizes['schema 2'] / sizes['schema 1']:.4f}"),
    ]  # fmt: skip
    data = {"loads_s": loads, "walk_s": walk, "sha256_s": sha, "save_s": t_write,
            "file_bytes": sizes, "nnz": nnz, "machine": machine()}  # fmt: skip
    if dense is not None:
        rows += [
            ("dense scan, fletcher32",
             f"{t_dense:.2f} s ({args.dense_size}x{args.dense_size}x151x151)"),
            ("dense scan, no fletcher32", f"{t_plain:.2f} s"),
            ("fletcher32 cost on a dense scan", f"{t_dense / t_plain:.2f}x"),
            ("statistics pass (view by view), fletcher32", f"{scans['stats']:.2f} s"),
            ("statistics pass, no fletcher32", f"{scans['stats_plain']:.2f} s "
                                               f"({scans['stats'] / scans['stats_plain']:.2f}x)"),
            ("statistics pass, 1 MiB chunk cache", f"{scans['stats_1mib']:.2f} s vs "
             f"{scans['stats_plain_1mib']:.2f} s without fletcher32 "
             f"({scans['stats_1mib'] / scans['stats_plain_1mib']:.2f}x)"),
        ]  # fmt: skip
        data["dense_scan_s"] = scans
    report(rows, data, args.json)


if __name__ == "__main__":
    main()
