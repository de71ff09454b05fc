"""The Dask executor (:class:`DaskExecutor`): tasks on the workers of a
``dask.distributed`` cluster, the worker plugin, and connecting to a scheduler or starting
a local cluster (:mod:`sparsebtf.execution` chooses it). Dask is imported only when used.
"""

from __future__ import annotations

import contextlib
import os
import socket
import sys
import uuid
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from .errors import SparseBTFError
from .executors import Executor, _add, _pairwise_sum


class ClusterError(SparseBTFError):
    """The Dask cluster cannot be reached, went away, or keeps losing the workers of a task."""


class DaskExecutor(Executor):
    """Tasks run on a ``dask.distributed`` cluster through ``client``.

    ``cluster`` (a ``LocalCluster`` this executor started) is closed with the executor; a
    client given by the caller is left open.
    """

    distributed = True

    def __init__(self, client: Any, cluster: Any = None, own_client: bool = False) -> None:
        self.client = client
        self.cluster = cluster
        self._own_client = own_client
        self._places: list[str] = []  # the workers ``submit(place=)`` spreads over
        self.address = str(client.scheduler.address)
        _register_worker_plugin(client)

    @property
    def n_workers(self) -> int:
        workers = self.client.scheduler_info().get("workers", {})
        return max(1, sum(int(w.get("nthreads", 1)) for w in workers.values()))

    @property
    def dashboard_link(self) -> str | None:
        """The scheduler's dashboard, if it serves one."""
        if "dashboard" not in self.client.scheduler_info().get("services", {}):
            return None
        return str(self.client.dashboard_link)

    def describe(self) -> str:
        workers = self.client.scheduler_info().get("workers", {})
        threads = sum(int(w.get("nthreads", 1)) for w in workers.values())
        link = self.dashboard_link
        kind = "local Dask cluster" if self.cluster is not None else "Dask scheduler"
        return (
            f"{kind} {self.address}: {len(workers)} workers, {threads} threads"
            + (f", dashboard {link}" if link else "")
        )

    def _key(self, fn: Callable[..., Any]) -> str:
        return f"sparsebtf-{getattr(fn, '__name__', 'task')}-{uuid.uuid4().hex}"

    def submit(self, fn: Callable[..., Any], *args: Any, ticks: bool = False,
               place: int | None = None) -> Any:
        where: dict[str, Any] = {}
        if place is not None:
            # Tasks follow their data, so where a held value is computed decides where the
            # later tasks on it run: left to the scheduler, the training partitions landed
            # 32 : 16 on two workers. A loose restriction spreads them and still lets another
            # worker take over. (nthreads() asks the scheduler, once per spread, at its slot
            # 0; scheduler_info() is a cache that may predate the workers.)
            if place == 0 or not self._places:
                self._places = sorted(self.client.nthreads())
            if self._places:
                where = {"workers": [self._places[place % len(self._places)]],
                         "allow_other_workers": True}  # fmt: skip
        return self.client.submit(fn, *args, key=self._key(fn), pure=False, **where)

    def constant(self, value: Any) -> Any:
        import dask

        # The value travels inside the graph (not scattered) so that the scheduler can
        # recompute it if the worker holding it dies.
        with dask.config.set({"distributed.admin.large-graph-warning-threshold": "4GiB"}):
            return self.client.submit(_identity, value, key=self._key(_identity), pure=False)

    def _ordered(self, items: list[Any], weights: list[int], pb: Any) -> Iterator[Any]:
        from distributed import as_completed

        index = {f.key: i for i, f in enumerate(items)}
        ready: dict[int, Any] = {}
        nxt = 0
        try:
            for fut in as_completed(items, loop=self.client.loop):
                i = index[fut.key]
                if fut.status != "finished":
                    self._raise(fut)
                pb.update(weights[i])
                ready[i] = fut
                while nxt in ready:
                    value = self._value(ready.pop(nxt))
                    items[nxt] = None
                    nxt += 1
                    yield value
        finally:
            left = [f for f in items if f is not None and f.status == "pending"]
            if left:
                with contextlib.suppress(Exception):
                    self.client.cancel(left)

    def _value(self, fut: Any) -> Any:
        try:
            return fut.result()
        except Exception as e:
            raise self._translate(e, fut) from e

    def _raise(self, fut: Any) -> None:
        self._value(fut)
        raise ClusterError(f"task {fut.key} ended as {fut.status!r}")  # pragma: no cover

    def _translate(self, e: Exception, fut: Any) -> Exception:
        from concurrent.futures import CancelledError

        from distributed.comm.core import CommClosedError
        from distributed.scheduler import KilledWorker

        if isinstance(e, SparseBTFError):
            return e
        if isinstance(e, KilledWorker):
            return ClusterError(
                f"task {fut.key} was running on every worker that died ({e}); are the workers "
                "running out of memory? give each one more (docs/distributed.md)"
            )
        if isinstance(e, CancelledError | CommClosedError | OSError | TimeoutError):
            why = " ".join(str(e).split()) or "connection closed"
            return ClusterError(
                f"lost the Dask scheduler at {self.address} ({type(e).__name__}: {why})"
            )
        return e

    def tree_sum(self, handles: Sequence[Any]) -> Any:
        return _pairwise_sum(list(handles), lambda a, b: self.submit(_add, a, b))

    def close(self) -> None:
        import logging

        # A client whose scheduler went away logs its reconnection failures as tracebacks;
        # the caller already has a one-line ClusterError.
        log = logging.getLogger("distributed.client")
        level = log.level
        if self.client.status != "running":
            log.setLevel(logging.CRITICAL)
        try:
            with contextlib.suppress(Exception):
                if self._own_client:
                    self.client.close()
        finally:
            log.setLevel(level)
        if self.cluster is not None:
            with contextlib.suppress(Exception):
                self.cluster.close()


def _identity(value: Any) -> Any:
    return value


def _reuse_array_memory() -> None:
    """Let glibc reuse freed blocks up to 32 MiB instead of mapping fresh pages for each.

    Dask's nanny starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which also switches off
    glibc's adaptive mmap threshold: every array above 128 KiB then becomes a new mmap, zeroed
    page by page on first touch. Measured on encoding: 8x the page faults of a plain process
    and 1.5-2x its CPU time; with these settings, fewer faults than a plain process.
    """
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:  # not glibc
        return
    m_trim_threshold, m_mmap_threshold = -1, -3  # <malloc.h>
    libc.mallopt(m_mmap_threshold, 32 * 2**20)
    libc.mallopt(m_trim_threshold, 64 * 2**20)


def _register_worker_plugin(client: Any) -> None:
    """On every worker, including those that join or restart later: one thread per task
    (unless the worker's environment sets ``SPARSEBTF_THREADS``) and array-friendly malloc."""
    from distributed.diagnostics.plugin import WorkerPlugin

    class SparseBTFWorker(WorkerPlugin):
        name = "sparsebtf-worker"
        idempotent = True

        def setup(self, worker: Any) -> None:
            os.environ.setdefault("SPARSEBTF_THREADS", "1")
            _reuse_array_memory()

    client.register_plugin(SparseBTFWorker())


def worker_label() -> str | None:
    """"Dask worker ADDRESS (host NAME)" inside a Dask task, None elsewhere."""
    if "distributed" not in sys.modules:
        return None
    from distributed import get_worker

    try:
        w = get_worker()
    except ValueError:
        return None
    return f"Dask worker {w.address} (host {socket.gethostname()})"


def _connect(address: str, timeout: float | None) -> Any:
    from distributed import Client

    kw = {} if timeout is None else {"timeout": timeout}
    try:
        return Client(address, set_as_default=False, **kw)
    except (OSError, TimeoutError, ValueError) as e:
        raise ClusterError(
            f"cannot reach the Dask scheduler at {address} ({type(e).__name__}: {e}); "
            "is 'dask scheduler' running there, and is the address tcp://HOST:PORT?"
        ) from None


def _local_cluster(workers: int, memory_limit: str | float, dashboard: bool) -> Any:
    import warnings

    from distributed import LocalCluster

    with warnings.catch_warnings():
        # Port 8787 taken: Dask serves the dashboard elsewhere, and we print where.
        warnings.filterwarnings("ignore", message=".*already in use.*")
        return LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            memory_limit=memory_limit,
            dashboard_address=":8787" if dashboard else ":0",
            scheduler_kwargs={"dashboard": dashboard},
        )
