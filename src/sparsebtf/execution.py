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

The executors live in :mod:`sparsebtf.executors` (the interface, :class:`InProcess`,
:class:`PairwiseSum`) and :mod:`sparsebtf.dask_executor` (:class:`DaskExecutor`); this module
chooses one (:class:`Execution`, :func:`executor`) and every name above is imported from it.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, ClassVar

from .constraints import Interval, Options, Rule
from .dask_executor import (
    ClusterError,
    DaskExecutor,
    _connect,
    _local_cluster,
    worker_label,
)
from .errors import BTFInputError
from .executors import (
    Executor,
    InProcess,
    PairwiseSum,
    _pairwise_sum,  # noqa: F401 - imported from here (tests)
)

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
