"""Worker threads for the whole pipeline: one BLAS thread per worker, one worker per core.

Independent work (projections, statistics of view groups, texel blocks) runs side by side on
one thread pool for the process. A projection is a chain of GEMMs on one data point (151×151
matrices against 15,100-column slabs). Splitting each small GEMM over two BLAS threads costs
more in synchronisation than it gains, and collapses when another process holds a core; giving
each core its own data point keeps every GEMM single-threaded and the cores busy. Numpy
releases the GIL inside BLAS and large array operations, so threads suffice (no copies between
processes).
``SPARSEBTF_THREADS`` sets the number of workers (default: the cores this process may use).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import numpy as np
from threadpoolctl import ThreadpoolController

T = TypeVar("T")
R = TypeVar("R")

__all__ = [
    "n_workers", "ordered_map", "parallel_map", "prefetch", "single_threaded_blas",
    "thread_buffer",
]  # fmt: skip

_POOL: ThreadPoolExecutor | None = None
_BLAS: ThreadpoolController | None = None


def single_threaded_blas():  # type: ignore[no-untyped-def]
    """A context limiting BLAS to one thread. One controller for the process: scanning the
    loaded libraries anew (``threadpool_limits``) cost 0.3 ms a call, on every batch."""
    global _BLAS
    if _BLAS is None:
        _BLAS = ThreadpoolController()
    return _BLAS.limit(limits=1, user_api="blas")


def thread_buffer(local: threading.local, size: int, dtype: np.dtype | type,
                  name: str = "buf") -> np.ndarray:  # fmt: skip
    """The first ``size`` entries of a flat ``dtype`` array owned by the calling thread (kept
    as ``local.<name>``, made anew only when too small or of another dtype): reused from call
    to call, so the kernel does not map and zero fresh pages for every call."""
    buf = getattr(local, name, None)
    if buf is None or buf.size < size or buf.dtype != dtype:
        buf = np.empty(size, dtype=dtype)
        setattr(local, name, buf)
    return buf[:size]


def n_workers() -> int:
    env = os.environ.get("SPARSEBTF_THREADS")
    if env and env.isdigit() and int(env) > 0:
        return int(env)
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return max(1, os.cpu_count() or 1)


def _pool(n: int) -> ThreadPoolExecutor:
    global _POOL
    if _POOL is None or _POOL._max_workers != n:  # type: ignore[attr-defined]
        _POOL = ThreadPoolExecutor(max_workers=n, thread_name_prefix="sparsebtf")
    return _POOL


def parallel_map(fn: Callable[[T], R], items: Iterable[T]) -> Iterator[R]:
    """``map(fn, items)`` over the worker threads with single-threaded BLAS, in order."""
    items = list(items)
    n = n_workers()
    if n == 1 or len(items) == 1:
        with single_threaded_blas():
            return iter([fn(x) for x in items])
    with single_threaded_blas():
        return iter(list(_pool(n).map(fn, items)))


def ordered_map(fn: Callable[[T], R], items: Iterable[T]) -> Iterator[R]:
    """``map(fn, items)`` over the worker threads with single-threaded BLAS, each result
    yielded in order as soon as it is ready (a progress bar can follow; a failure is raised
    when its turn comes). Call it from the main thread, not from a worker."""
    items = list(items)
    n = n_workers()
    if n == 1 or len(items) <= 1:
        yield from map(fn, items)
        return
    with single_threaded_blas():
        yield from _pool(n).map(fn, items)


def prefetch(iterable: Iterable[T], depth: int = 1) -> Iterator[T]:
    """Iterate ``iterable`` in a background thread, ``depth`` items ahead.

    Reading and preprocessing the next batch of data points (h5py, log, YUV: GIL-free numpy)
    then overlaps the projections of the current one instead of idling the workers.
    Exceptions of the producer are re-raised in the consumer.
    """
    import queue
    import threading

    q: queue.Queue[tuple[str, object]] = queue.Queue(maxsize=max(1, depth))
    stop = threading.Event()

    def produce() -> None:
        try:
            for item in iterable:
                if stop.is_set():
                    return
                q.put(("item", item))
            q.put(("done", None))
        except BaseException as e:
            q.put(("error", e))

    thread = threading.Thread(target=produce, name="sparsebtf-prefetch", daemon=True)
    thread.start()
    try:
        while True:
            kind, value = q.get()
            if kind == "done":
                return
            if kind == "error":
                raise value  # type: ignore[misc]
            yield value  # type: ignore[misc]
    finally:
        stop.set()
        while thread.is_alive():
            try:
                q.get_nowait()
            except queue.Empty:
                thread.join(timeout=0.05)
