"""Where the work runs: in this process (the default) or on a Dask cluster.

Training, encoding and the quality benchmark hand their work to an :class:`Executor` as tasks
(pure functions of their arguments) and read the results back in a fixed order, so the same
code runs in one process and on many machines and gives the same numbers.

* :class:`InProcess` (default): tasks run here, one after the other, when their results are
  asked for. Inside a task the array kernels keep today's parallelism (one thread per core,
  one BLAS thread each: :mod:`sparsebtf._threads`). Dask is not imported.
* :class:`DaskExecutor`: tasks run on the workers of a ``dask.distributed`` cluster, one task
  per worker thread (each task single-threaded: a worker plugin sets ``SPARSEBTF_THREADS=1``
  unless the worker's environment sets it). :func:`executor` starts a ``LocalCluster`` of
  ``workers`` processes on this machine or connects to a running scheduler (``scheduler=`` or
  :data:`SCHEDULER_ENV`), and prints the dashboard address.

The interface (both executors)::

    with executor(client=None, scheduler=None, workers=None) as ex:
        h = ex.submit(fn, *args)          # a handle: a Dask future, or a deferred local call
        c = ex.constant(value)            # a value every task may use (model, dictionaries)
        for r in ex.results([ex.submit(task, c, lo, hi) for lo, hi in ex.chunks(n, 4)]):
            ...                           # in submission order; one bar with ETA meanwhile
        total = ex.gather([ex.tree_sum(parts)])[0]   # fixed pairing: deterministic sums

Handles may be passed as arguments of later tasks (Dask moves the data between workers).
A Dask handle stays valid while it is held, and if the worker holding its value dies, Dask
recomputes it from its function and arguments (its *lineage*); :meth:`Executor.constant` puts
the value itself into the task graph for the same reason, so nothing is ever lost with a
worker: a killed worker costs the tasks it was running, which run again elsewhere.
:meth:`Executor.results` releases each result once read; do not keep the list of handles.

Training uses it through :mod:`sparsebtf.learning.partitions` (one task per fixed-size
partition of the training points: a load task on a cluster, whose result stays in worker
memory across iterations; coding and cross-product tasks next to it; dictionaries broadcast
with :meth:`Executor.constant` each pass; sums by :meth:`Executor.tree_sum`, or in process by
:class:`PairwiseSum`, the same pairing one value at a time), encoding through
:mod:`sparsebtf.codec.jobs`. A partition is described by its source (BTF paths, point
indices, statistics), never by its data, so one lost with its worker is rebuilt from the BTFs
by Dask's lineage; partitions are fixed numbers of points (not a share per worker) and sums
use a fixed tree, so the model does not depend on the number of workers and equals a
one-process run (where the same tasks run in order here).
"""

from __future__ import annotations

import abc
import contextlib
import math
import os
import socket
import sys
import uuid
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

from ._progress import bar
from .constraints import Interval, Options, Rule
from .errors import BTFInputError, SparseBTFError

__all__ = [
    "SCHEDULER_ENV",
    "ClusterError",
    "DaskExecutor",
    "Execution",
    "Executor",
    "InProcess",
    "PairwiseSum",
    "executor",
    "worker_label",
]

#: Environment variable naming the Dask scheduler to use when none is given.
SCHEDULER_ENV = "SPARSEBTF_SCHEDULER"


class ClusterError(SparseBTFError):
    """The Dask cluster cannot be reached, went away, or keeps losing the workers of a task."""


def _pairwise_sum(items: list[Any], add: Callable[[Any, Any], Any]) -> Any:
    """((a0 + a1) + (a2 + a3)) + …: the same pairing whatever runs the additions."""
    if not items:
        raise SparseBTFError("nothing to sum")
    while len(items) > 1:
        paired = [add(items[i], items[i + 1]) for i in range(0, len(items) - 1, 2)]
        items = paired + ([items[-1]] if len(items) % 2 else [])
    return items[0]


def _add(a: Any, b: Any) -> Any:
    return a + b


class PairwiseSum:
    """The sum of values added one by one, paired as :meth:`Executor.tree_sum` pairs them.

    Keeps one partial sum per set bit of the count so far (a binary counter), so summing n
    values holds log2(n) of them instead of n; the final right-to-left fold gives the same
    pairing as the level-by-level tree (``tests/test_distributed_training.py`` checks it), so
    a stream summed in process has the same bits as the tree summed on a cluster.
    """

    def __init__(self, add: Callable[[Any, Any], Any] = _add) -> None:
        self._add = add
        self._stack: list[tuple[int, Any]] = []  # (number of values, their sum)

    def add(self, value: Any) -> None:
        size = 1
        while self._stack and self._stack[-1][0] == size:
            value = self._add(self._stack.pop()[1], value)
            size *= 2
        self._stack.append((size, value))

    def total(self) -> Any:
        if not self._stack:
            raise SparseBTFError("nothing to sum")
        value = self._stack[-1][1]
        for _, left in reversed(self._stack[:-1]):
            value = self._add(left, value)
        return value


class Executor(abc.ABC):
    """Runs tasks and hands back their results in order (see the module docstring)."""

    #: True when tasks run on other processes (arguments and results are pickled).
    distributed: bool = False

    @property
    @abc.abstractmethod
    def n_workers(self) -> int:
        """Tasks that can run at once (worker threads; 1 in process)."""

    @abc.abstractmethod
    def submit(
        self, fn: Callable[..., Any], *args: Any, ticks: bool = False, place: int | None = None
    ) -> Any:
        """A handle on ``fn(*args)``; handles among ``args`` stand for their values.

        With ``ticks`` the function takes a keyword ``tick``: in process it is the progress
        bar's ``update`` (call ``tick(n)`` as work gets done); on a cluster it is None and the
        bar advances by the task's weight when the task ends. ``place`` (on a cluster): run on
        worker ``place`` mod the number of workers if it can, for a value later tasks use
        where it lies.
        """

    @abc.abstractmethod
    def constant(self, value: Any) -> Any:
        """A handle on ``value``, for tasks to share (sent once per worker, never lost)."""

    def results(
        self,
        handles: Iterable[Any],
        *,
        weights: Sequence[int] | None = None,
        desc: str = "",
        unit: str = "it",
        progress: bool | None = None,
    ) -> Iterator[Any]:
        """The values of ``handles`` in order, under one progress bar (ETA) of ``weights``.

        The first failing task raises (the others are cancelled); each value is released on
        the executor once yielded (the caller should not keep its list of handles).
        """
        items = list(handles)
        handles = ()
        w = list(weights) if weights is not None else [1] * len(items)
        with bar(sum(w), desc, unit, progress) as pb:
            yield from self._ordered(items, w, pb)

    @abc.abstractmethod
    def _ordered(self, items: list[Any], weights: list[int], pb: Any) -> Iterator[Any]:
        """:meth:`results` without its bar: advance ``pb`` as the work is done."""

    def gather(self, handles: Iterable[Any]) -> list[Any]:
        """The values of ``handles``, in order, without a bar."""
        return list(self.results(handles, progress=False))

    @abc.abstractmethod
    def tree_sum(self, handles: Sequence[Any]) -> Any:
        """A handle on the sum of the values of ``handles``, added in a fixed pairwise tree
        (so the result is bit for bit the same in process and on any cluster)."""

    def chunks(
        self, n: int, align: int = 1, per_worker: int = 4, at_most: int | None = None,
        total: int | None = None,
    ) -> list[tuple[int, int]]:  # fmt: skip
        """Split ``range(n)`` into ``[lo, hi)`` ranges whose starts are multiples of ``align``.

        In process: one range (the task streams it and shows fine-grained progress). On a
        cluster: about ``per_worker`` ranges per worker thread for a job of ``total`` items
        (default ``n``: when several inputs share the workers, give the sum), at most
        ``at_most`` long (rounded to ``align``), so work balances, progress moves and a lost
        worker costs little.
        """
        if n <= 0:
            return []
        if not self.distributed:
            return [(0, n)]
        size = math.ceil((total or n) / (per_worker * max(1, self.n_workers)))
        if at_most is not None:
            size = min(size, at_most)
        size = max(align, math.ceil(size / align) * align)
        return [(lo, min(lo + size, n)) for lo in range(0, n, size)]

    def describe(self) -> str:
        return "in process"

    def close(self) -> None:  # noqa: B027 - nothing to release in process
        """Release what this executor started."""


class _Deferred:
    """A local task: run on first use, its value kept while the handle is held."""

    __slots__ = ("args", "fn", "ticks", "value")

    _UNSET = object()

    def __init__(self, fn: Callable[..., Any], args: tuple[Any, ...], ticks: bool) -> None:
        self.fn, self.args, self.ticks = fn, args, ticks
        self.value: Any = _Deferred._UNSET

    def result(self, tick: Callable[[int], Any] | None = None) -> Any:
        if self.value is _Deferred._UNSET:
            args = [_resolve(a) for a in self.args]
            kw = {"tick": tick} if self.ticks else {}
            self.value = self.fn(*args, **kw)
            self.fn, self.args = None, ()  # type: ignore[assignment]
        return self.value

    @classmethod
    def of(cls, value: Any) -> _Deferred:
        d = cls(lambda: value, (), False)
        d.value = value
        return d


def _resolve(x: Any) -> Any:
    """Handles inside an argument (also in lists, tuples, dicts, as Dask does) → values."""
    if isinstance(x, _Deferred):
        return x.result()
    if isinstance(x, list | tuple):
        return type(x)(_resolve(v) for v in x)
    if isinstance(x, dict):
        return {k: _resolve(v) for k, v in x.items()}
    return x


class InProcess(Executor):
    """Tasks run in this process, in order, when their results are read."""

    distributed = False

    @property
    def n_workers(self) -> int:
        return 1

    def submit(
        self, fn: Callable[..., Any], *args: Any, ticks: bool = False, place: int | None = None
    ) -> _Deferred:
        return _Deferred(fn, args, ticks)

    def constant(self, value: Any) -> _Deferred:
        return _Deferred.of(value)

    def _ordered(self, items: list[Any], weights: list[int], pb: Any) -> Iterator[Any]:
        for i, h in enumerate(items):
            items[i] = None  # release each value once handed over
            if h.ticks and h.value is _Deferred._UNSET:
                yield h.result(pb.update)
            else:
                value = h.result()
                pb.update(weights[i])
                yield value

    def tree_sum(self, handles: Iterable[Any]) -> _Deferred:
        """Eager, holding log2(n) partial sums (a generator of handles: one value at a time)."""
        acc = PairwiseSum()
        for h in handles:
            acc.add(h.result())
        return _Deferred.of(acc.total())


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


def _is_client(value: Any) -> bool:
    """A ``distributed.Client`` (by its interface: Dask need not be imported) or an Executor."""
    return isinstance(value, Executor) or (hasattr(value, "submit") and hasattr(value, "scheduler"))


@dataclass(frozen=True, kw_only=True)
class Execution(Options):
    """Where work runs: in this process (the default); on a local Dask cluster of ``workers``
    single-threaded processes; on the cluster of ``scheduler`` (an address such as
    ``tcp://10.0.0.5:8786``; default :data:`SCHEDULER_ENV` if set); or through ``client``
    (a ``dask.distributed.Client``, or an :class:`Executor`, used as it is). The results do
    not depend on it. Training and every encoder take one (``execution=``), or the same
    keywords."""

    client: Any = None
    scheduler: str | None = None
    workers: int | None = None

    constraints: ClassVar[dict[str, list[Any]]] = {
        "client": [Rule(_is_client, "a dask.distributed.Client or an Executor"), None],
        "scheduler": [str, None],
        "workers": [Interval(int, 1, None, unit="(worker processes)"), None],
    }
    argument = "execution"

    def check(self) -> None:
        if self.workers is not None and self.scheduler:
            raise BTFInputError("give either workers (a local cluster) or a scheduler, not both")

    @classmethod
    def take(cls, base: Execution | None, keywords: dict[str, Any]
             ) -> tuple[Execution, dict[str, Any]]:  # fmt: skip
        """``base`` with this object's keywords of ``keywords`` in place, and the other
        keywords (a function's options besides where it runs)."""
        mine = {k: v for k, v in keywords.items() if k in cls.names()}
        return cls.build(base, **mine), {k: v for k, v in keywords.items() if k not in mine}

    def executor(self, **kwargs: Any) -> contextlib.AbstractContextManager[Executor]:
        """:func:`executor` of this place (``kwargs``: its keyword-only arguments)."""
        return executor(self.client, self.scheduler, self.workers, **kwargs)


@contextlib.contextmanager
def executor(
    client: Any = None,
    scheduler: str | None = None,
    workers: int | None = None,
    *,
    memory_limit: str | float = "auto",
    dashboard: bool = True,
    timeout: float | None = None,
    announce: bool = True,
) -> Iterator[Executor]:
    """The executor of ``client`` / ``scheduler`` / ``workers`` (:class:`Execution`), closed
    (if we started it) when the block ends. A local cluster's workers get ``memory_limit``
    each ("auto" shares this machine's memory); ``timeout`` (seconds) bounds connecting
    (default: Dask's ``distributed.comm.timeouts.connect``); ``announce`` prints the cluster
    and its dashboard address on stderr."""
    Execution(client=client, scheduler=scheduler, workers=workers)  # one line if unusable
    if isinstance(client, Executor):
        yield client
        return
    if client is not None:
        ex: Executor = DaskExecutor(client)
        yield ex
        return
    address = scheduler or (None if workers else os.environ.get(SCHEDULER_ENV) or None)
    if address is None and workers is None:
        yield InProcess()
        return
    if address is not None:
        ex = DaskExecutor(_connect(address, timeout), own_client=True)
    else:
        cluster = _local_cluster(int(workers), memory_limit, dashboard)  # type: ignore[arg-type]
        try:
            from distributed import Client

            ex = DaskExecutor(Client(cluster, set_as_default=False), cluster, own_client=True)
        except BaseException:
            cluster.close()
            raise
    try:
        if announce:
            print(f"sparsebtf: {ex.describe()}", file=sys.stderr)
        yield ex
    finally:
        ex.close()
