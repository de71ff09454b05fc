"""Clusters and background commands for the distributed tests (started and stopped here)."""

from __future__ import annotations

import contextlib
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

from sparsebtf.cli.main import main


def wait_for(path: Path, timeout: float = 60.0) -> None:
    t = time.monotonic()
    while not path.exists():
        assert time.monotonic() - t < timeout, f"{path} never appeared"
        time.sleep(0.02)


def command_in_thread(argv: list) -> tuple[threading.Thread, dict]:
    """Run ``sparsebtf ARGV`` in a thread; its exit code lands in the dict under "code"."""
    result: dict = {}

    def target():
        result["code"] = main([str(a) for a in argv])

    th = threading.Thread(target=target)
    th.start()
    return th, result


@contextlib.contextmanager
def cli_cluster(tmp_path: Path, setup=None) -> Iterator[tuple[str, subprocess.Popen]]:
    """A ``dask scheduler`` and one single-threaded ``dask worker`` (subprocesses on 127.0.0.1);
    yields (address, the scheduler's process), after running ``setup(client)``."""
    import distributed

    sched_file = tmp_path / "scheduler.json"
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    sched = subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
         "--port", "0", "--no-dashboard", "--scheduler-file", str(sched_file)], **quiet,
    )  # fmt: skip
    worker = None
    try:
        wait_for(sched_file, 30)
        with distributed.Client(scheduler_file=str(sched_file), timeout=30) as c:
            address = c.scheduler.address
            worker = subprocess.Popen(
                [sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads",
                 "1", "--no-dashboard", "--host", "127.0.0.1"], **quiet,
            )  # fmt: skip
            c.wait_for_workers(1, timeout=30)
            if setup is not None:
                setup(c)
        yield address, sched
    finally:
        for p in (sched, worker):
            if p is not None:
                p.kill()
                p.wait()
