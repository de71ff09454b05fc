"""Code the distributed tests run on Dask workers (few imports: workers import this module)."""

from __future__ import annotations

import os
import time
from pathlib import Path


def slow_reads(marks: str, delay: float) -> None:
    """On a worker: every read of a data point (all views) from a dense file waits ``delay`` s
    and leaves a mark named by the worker's pid: a worker that left a mark is coding."""
    from sparsebtf.data.dense_file import DenseFileBTF

    read = DenseFileBTF.read

    def slow(self, rows, cols, lights, views):
        if isinstance(views, slice):
            Path(marks, str(os.getpid())).touch()
            time.sleep(delay)
        return read(self, rows, cols, lights, views)

    DenseFileBTF.read = slow


def slow_coding(marks: str, delay: float) -> None:
    """On a worker: every coding step of training waits ``delay`` s and leaves a mark named by
    the worker's pid (a worker that left a mark is training)."""
    import sparsebtf.learning.partitions as partitions

    step = partitions.code_step

    def slow(*args, **kw):
        Path(marks, str(os.getpid())).touch()
        time.sleep(delay)
        return step(*args, **kw)

    partitions.code_step = slow
