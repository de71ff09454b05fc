"""The executor interface (:class:`Executor`), its in-process form (:class:`InProcess`)
and the fixed-order sums both use (:class:`PairwiseSum`); :mod:`sparsebtf.execution`
describes them and chooses where work runs.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any

from ._progress import bar
from .errors import SparseBTFError


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
