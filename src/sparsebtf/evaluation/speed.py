"""Table 1's "fast local reconstruction", measured: single BTF values decoded per second.

The paper's criterion (c) asks for "fast access to single elements within the 7D BTF
function"; Table 1 only ticks it. :func:`decode_speed` times it for each reconstruction of the
benchmark: random single-value queries (row, col, light, view) — all indices on the measured
grid, from a seeded generator, the same queries for every reconstruction of one shape — at
batch size 1 (one query per call: the latency a scalar renderer sees) and at ``batch`` queries
per call (the throughput of a wavefront renderer). What runs, per reconstruction
(:func:`single_value_lookup`):

* a SparseBTF reconstruction (:class:`~sparsebtf.runtime.dense.DecodedBTF`, log-YUV codes in
  channels Y, U, V) — the runtime's lookup :meth:`sparsebtf.runtime.RuntimeBTF.evaluate`
  (float32, every stored coefficient) at the measured directions with ``nearest``
  interpolation, i.e. Eq. 5 on the query's data point, then the inverse preprocessing; the
  backend is numba when installed (compiled, parallel over queries), else NumPy;
* a reconstruction with a ``query(rows, cols, lights, views)`` method (four equal-length int
  arrays → (n, 3) linear RGB; the neural baselines) — that method;
* any other BTF — ``read`` of one value per call (the batched rate is not measured: ``read``
  returns outer products of its indices, not values at a list of queries).

Every rate is queries / wall seconds over as many calls as fit in ``seconds`` (at least one),
after one untimed call (numba's compilation, caches). Batch 1 runs on one thread (numba, BLAS
and torch limited to 1 for its loop, as a renderer calls it from each of its own threads): a
parallel launch for one query times thread wake-ups, not the decode — 14 ms a query with 2
numba threads on a loaded 2-core machine against 0.14 ms with one. The batched rate uses every
thread the backend has (reported).
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from typing import Any

import numpy as np

from ..data.btf import BTF
from ..errors import BTFInputError, SparseBTFError
from ..runtime import kernels
from ..runtime.decoder import RuntimeBTF
from ..runtime.dense import DecodedBTF

__all__ = ["BATCH1_POOL", "decode_speed", "random_queries", "single_value_lookup"]

#: Distinct queries the batch-1 loop cycles through (each call takes the next one).
BATCH1_POOL = 4096

#: A lookup: (rows, cols, lights, views) int arrays of one length n → (n, 3) linear RGB.
Lookup = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]


def random_queries(btf: BTF, n: int, seed: int = 0) -> tuple[np.ndarray, ...]:
    """``n`` uniform random (rows, cols, lights, views) int64 arrays on ``btf``'s grid."""
    rng = np.random.default_rng(seed)
    h, w, nl, nv, _ = btf.shape
    return tuple(rng.integers(0, m, n) for m in (h, w, nl, nv))


def _cpus() -> int:
    """The cores this process may use."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def _blas_threads() -> int:
    from threadpoolctl import threadpool_info

    return max((int(p.get("num_threads", 1)) for p in threadpool_info()
                if p.get("user_api") == "blas"), default=1)  # fmt: skip


def single_value_lookup(rec: BTF) -> tuple[Lookup, dict[str, Any]]:
    """The single-value lookup :func:`decode_speed` times for ``rec``, and what it is:
    {"path", "backend", "threads", "threads_of", "batched", and "note" when the runtime
    refused a coded BTF}."""
    note = None
    if isinstance(rec, DecodedBTF):
        try:
            rt = RuntimeBTF(rec.coded)
        except BTFInputError as exc:  # e.g. raw-RGB or 5D codes: not a runtime material
            note = f"runtime refused the codes ({exc}); timed read() instead"
        else:
            backend = "numba" if kernels.HAVE_NUMBA else "numpy"
            lxyz, vxyz = rt.coded.lights.xyz, rt.coded.views.xyz

            def runtime(rows, cols, lights, views):
                return rt.evaluate(lxyz[lights], vxyz[views], texel=np.stack([rows, cols], 1),
                                   interpolation="nearest", backend=backend)  # fmt: skip

            if backend == "numba":
                from .._numba import numba

                threads, of = int(numba.get_num_threads()), "numba"
            else:
                threads, of = _blas_threads(), "BLAS"
            return runtime, {
                "path": "RuntimeBTF.evaluate (Eq. 5, nearest measured direction, float32)",
                "backend": backend, "threads": threads, "threads_of": of, "batched": True,
            }  # fmt: skip
    query = getattr(rec, "query", None)
    if callable(query):
        info: dict[str, Any] = {"path": f"{type(rec).__name__}.query", "batched": True}
        torch = sys.modules.get("torch")
        if torch is not None:
            info.update(backend="torch", threads=int(torch.get_num_threads()),
                        threads_of="torch")  # fmt: skip
            device = getattr(rec, "device", None)
            if isinstance(device, torch.device) and device.type != "cpu":
                info["backend"] = f"torch {device}"  # a GPU's decode (neural methods)
        else:
            info.update(backend=type(rec).__name__, threads=_blas_threads(), threads_of="BLAS")
        return query, info

    def read_one(rows, cols, lights, views):
        values = [rec.read([r], [c], [li], [v])[0, 0, 0, 0]
                  for r, c, li, v in zip(rows, cols, lights, views, strict=True)]  # fmt: skip
        return np.stack(values)

    info = {"path": f"{type(rec).__name__}.read (one value per call)",
            "backend": type(rec).__name__, "threads": _blas_threads(), "threads_of": "BLAS",
            "batched": False}  # fmt: skip
    if note:
        info["note"] = note
    return read_one, info


@contextmanager
def _one_thread() -> Iterator[None]:
    """numba, BLAS and (when loaded) torch limited to one thread; restored afterwards."""
    from .._numba import numba
    from .._threads import single_threaded_blas

    torch = sys.modules.get("torch")
    nb_threads = numba.get_num_threads() if numba is not None else None
    torch_threads = torch.get_num_threads() if torch is not None else None
    try:
        if numba is not None:
            numba.set_num_threads(1)
        if torch is not None:
            torch.set_num_threads(1)
        with single_threaded_blas():
            yield
    finally:
        if nb_threads is not None:
            numba.set_num_threads(nb_threads)
        if torch_threads is not None:
            torch.set_num_threads(torch_threads)


def _rate(fn: Lookup, queries: tuple[np.ndarray, ...], per_call: int, seconds: float) -> dict:
    """Queries per second of ``fn`` on consecutive slices of ``per_call`` queries (cycling
    through ``queries``), over as many calls as fit in ``seconds``, after one untimed call."""
    n = queries[0].size
    starts = range(0, n - per_call + 1, per_call)
    out = np.asarray(fn(*(q[:per_call] for q in queries)))
    if out.shape != (per_call, 3):
        raise SparseBTFError(f"a lookup of {per_call} queries returned shape {out.shape}, "
                             f"expected ({per_call}, 3)")  # fmt: skip
    calls = 0
    t0 = time.perf_counter()
    while True:
        s = starts[calls % len(starts)]
        fn(*(q[s : s + per_call] for q in queries))
        calls += 1
        elapsed = time.perf_counter() - t0
        if elapsed >= seconds:
            break
    return {"queries_per_second": calls * per_call / elapsed, "calls": calls,
            "seconds": elapsed}  # fmt: skip


def decode_speed(
    reconstructions: Mapping[str, BTF],
    *,
    batch: int = 65536,
    seconds: float = 1.0,
    seed: int = 0,
) -> dict[str, dict]:
    """Single-value decodes per second of every reconstruction, at batch 1 and at ``batch``.

    Returns per label: ``path`` (what was timed, :func:`single_value_lookup`), ``backend``,
    ``threads`` and ``threads_of`` (numba, torch or BLAS threads of the batched rate;
    ``threads_1`` = 1 for batch 1), ``cpus`` (cores this process may use), ``batch_sizes``
    ([1, batch], or [1] for ``read``-only BTFs), ``queries_per_second_1``,
    ``queries_per_second_batch`` (None when not batched), ``calls_1``/``calls_batch`` and
    ``seconds_1``/``seconds_batch`` (what the rates are over), ``batch``, ``seed``.
    Queries: :func:`random_queries` with ``seed`` (``batch`` of them, at least
    :data:`BATCH1_POOL`; the batch-1 loop cycles through the first :data:`BATCH1_POOL`).
    """
    if batch < 1:
        raise BTFInputError(f"batch must be >= 1, got {batch}")
    if not (seconds > 0 and np.isfinite(seconds)):
        raise BTFInputError(f"seconds must be positive, got {seconds}")
    out: dict[str, dict] = {}
    for label, rec in reconstructions.items():
        fn, info = single_value_lookup(rec)
        queries = random_queries(rec, max(batch, BATCH1_POOL), seed)
        with _one_thread():
            one = _rate(fn, tuple(q[:BATCH1_POOL] for q in queries), 1, seconds)
        res = {**info, "batch_sizes": [1, batch] if info["batched"] else [1],
               "queries_per_second_1": one["queries_per_second"], "calls_1": one["calls"],
               "seconds_1": one["seconds"], "threads_1": 1, "queries_per_second_batch": None,
               "calls_batch": None, "seconds_batch": None, "batch": batch, "seed": seed,
               "cpus": _cpus()}  # fmt: skip
        if info["batched"]:
            many = _rate(fn, tuple(q[:batch] for q in queries), batch, seconds)
            res.update(queries_per_second_batch=many["queries_per_second"],
                       calls_batch=many["calls"], seconds_batch=many["seconds"])  # fmt: skip
        out[label] = res
    return out
