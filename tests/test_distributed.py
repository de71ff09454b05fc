"""The execution seam and encoding on a real Dask cluster (worker processes on 127.0.0.1).

Every cluster here is started by the test (``LocalCluster`` of processes, or ``dask scheduler``
/ ``dask worker`` subprocesses) and closed by it.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from sparsebtf.cli.main import main
from sparsebtf.codec import encode, encode_many, encode_to_size
from sparsebtf.data.dense_file import write_dense
from sparsebtf.errors import FileFormatError
from sparsebtf.execution import InProcess, executor
from sparsebtf.storage import load_coded, save_coded, save_model

from ._cluster import cli_cluster, command_in_thread
from ._workers import slow_reads
from .conftest import smooth_btf, tiny_model

distributed = pytest.importorskip("distributed")

CODE_FIELDS = ("membership", "counts", "values", "locations", "errors")


def local_cluster(n: int = 2):
    return distributed.LocalCluster(
        n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
        dashboard_address=":0", scheduler_kwargs={"dashboard": False},
    )  # fmt: skip


@pytest.fixture(scope="module")
def client():
    with local_cluster() as cluster, distributed.Client(cluster) as c:
        yield c


@pytest.fixture(scope="module")
def model():
    return tiny_model()


@pytest.fixture
def inputs(tmp_path, model):
    """Three dense BTF files of different sizes and a model file."""
    paths = []
    for s, size in enumerate((16, 12, 8)):
        p = tmp_path / f"m{s}.h5"
        write_dense(p, smooth_btf(10 + s, size=size))
        paths.append(str(p))
    save_model(model, tmp_path / "model.h5")
    return tmp_path, paths


def assert_same_codes(a, b):
    assert a.codes.keys() == b.codes.keys()
    for ch in a.codes:
        for f in CODE_FIELDS:
            x, y = getattr(a.codes[ch], f), getattr(b.codes[ch], f)
            assert x.dtype == y.dtype and np.array_equal(x, y), (ch, f)
    assert np.array_equal(a.stats.mean, b.stats.mean)
    assert np.array_equal(a.stats.std, b.stats.std)


# -- the seam ---------------------------------------------------------------------------------


def test_in_process_default_never_imports_dask(tmp_path):
    code = (
        "import sys; sys.path.insert(0, 'tests');"
        "from conftest import smooth_btf, tiny_model;"
        "from sparsebtf.codec import encode;"
        "encode(smooth_btf(1), tiny_model(1), tau=(16, 4, 4), progress=False);"
        "assert 'distributed' not in sys.modules and 'dask' not in sys.modules, 'dask imported'"
    )
    env = {**os.environ, "SPARSEBTF_SCHEDULER": ""}
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                       cwd=Path(__file__).parents[1])  # fmt: skip
    assert r.returncode == 0, r.stderr


def test_in_process_runs_tasks_in_order_and_lazily():
    ex = InProcess()
    calls = []

    def task(x, tick=None):
        calls.append(x)
        tick(x)
        return x * 10

    hs = [ex.submit(task, i, ticks=True) for i in range(1, 4)]
    assert calls == []  # nothing runs before its result is read
    assert list(ex.results(hs, weights=[1, 2, 3], progress=False)) == [10, 20, 30]
    assert calls == [1, 2, 3]
    assert ex.chunks(10, 4) == [(0, 10)]
    nested = ex.submit(lambda d: d["a"][1] + 1, {"a": [0, ex.constant(41)]})
    assert ex.gather([nested]) == [42]  # handles inside containers resolve, as on Dask


def test_tree_sum_is_the_same_bits_in_process_and_on_a_cluster(client):
    rng = np.random.default_rng(0)
    # Values whose sum depends on the order of the additions.
    parts = [rng.standard_normal(64) * 10.0 ** rng.integers(-8, 8) for _ in range(7)]
    local = InProcess()
    want = local.gather([local.tree_sum([local.constant(p) for p in parts])])[0]
    assert not np.array_equal(want, sum(parts[1:], parts[0]))  # the order matters here
    with executor(client=client) as ex:
        got = ex.gather([ex.tree_sum([ex.constant(p) for p in parts])])[0]
        assert ex.n_workers == 2
        ranges = ex.chunks(100, 4, per_worker=4, at_most=8)
        ex_chunks = ex.chunks(25, 5, per_worker=4, total=80)
    assert np.array_equal(want, got)
    assert ranges[0] == (0, 8) and ranges[-1] == (96, 100)
    assert all(lo % 4 == 0 for lo, _ in ranges)
    # One of many inputs: ranges are sized on the whole job (here 4 ranges per thread of 80).
    assert ex_chunks == [(0, 10), (10, 20), (20, 25)]


def test_workers_and_scheduler_are_exclusive():
    with pytest.raises(Exception, match="not both"), executor(workers=1, scheduler="tcp://x:1"):
        pass


# -- encoding on a cluster --------------------------------------------------------------------


def test_three_btfs_into_a_folder_equal_three_one_process_encodes(client, inputs, capsys):
    tmp, paths = inputs
    address = client.scheduler.address
    out = tmp / "out"
    argv = ["encode", *paths, "-m", tmp / "model.h5", "-o", f"{out}/", "--tau", "16,4,4",
            "--eps", "1e-4", "--scheduler", address]  # fmt: skip
    assert main([str(a) for a in argv]) == 0
    assert "Dask scheduler" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == [f"m{s}.coded.h5" for s in range(3)]
    for s, p in enumerate(paths):
        single = tmp / f"single{s}.h5"
        argv = ["encode", p, "-m", tmp / "model.h5", "-o", single, "--tau", "16,4,4",
                "--eps", "1e-4"]  # fmt: skip
        assert main([str(a) for a in argv]) == 0
        assert_same_codes(load_coded(out / f"m{s}.coded.h5"), load_coded(single))


def test_rate_control_on_a_cluster_equals_one_process(client, model):
    btf = smooth_btf(3, size=16)
    want = encode_to_size(btf, model, target_ratio=30, progress=False)
    got = encode_to_size(btf, model, target_ratio=30, progress=False, client=client)
    assert_same_codes(want, got)
    assert got.params["rate_control"] == want.params["rate_control"]


def test_worker_that_cannot_open_a_path_is_named(client, model, tmp_path):
    missing = tmp_path / "not-on-this-storage.h5"
    with pytest.raises(FileFormatError) as e:
        list(encode_many([missing], model, client=client, progress=False))
    msg = str(e.value)
    assert "\n" not in msg
    assert "Dask worker tcp://127.0.0.1:" in msg and str(missing) in msg


def test_unreachable_scheduler_is_one_line(inputs, capsys):
    import dask

    tmp, paths = inputs
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        code = main(["encode", paths[0], "-m", str(tmp / "model.h5"), "-o", str(tmp / "x.h5"),
                     "--scheduler", "tcp://127.0.0.1:9"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("sparsebtf: error: cannot reach the Dask scheduler at tcp://127.0.0.1:9")
    assert err.count("\n") == 1
    assert not (tmp / "x.h5").exists()


# -- losing a worker, losing the scheduler ------------------------------------------------------


def _wait_for_mark(marks: Path, timeout: float = 30.0) -> int:
    t = time.monotonic()
    while time.monotonic() - t < timeout:
        found = list(marks.iterdir())
        if found:
            return int(found[0].name)
        time.sleep(0.02)
    raise AssertionError("no worker started reading")


def test_worker_killed_mid_encoding_changes_nothing(inputs, tmp_path):
    tmp, paths = inputs
    marks = tmp_path / "marks"
    marks.mkdir()
    out = tmp / "out"
    with local_cluster() as cluster, distributed.Client(cluster) as c:
        c.run(slow_reads, str(marks), 0.03)
        th, result = command_in_thread(
            ["encode", *paths, "-m", tmp / "model.h5", "-o", f"{out}/", "--tau", "16,4,4",
             "--scheduler", cluster.scheduler_address]
        )  # fmt: skip
        victim = _wait_for_mark(marks)
        assert th.is_alive()
        os.kill(victim, signal.SIGKILL)
        th.join(timeout=120)
        assert result.get("code") == 0
        assert victim not in c.run(os.getpid).values()  # the nanny started a new process
    assert sorted(p.name for p in out.iterdir()) == [f"m{s}.coded.h5" for s in range(3)]
    one_process = encode_many(paths, tiny_model(), tau=(16, 4, 4), progress=False)
    for s, want in enumerate(one_process):
        save_coded(want, tmp_path / "want.h5")
        assert_same_codes(load_coded(out / f"m{s}.coded.h5"), load_coded(tmp_path / "want.h5"))


def test_a_shared_value_survives_the_worker_that_held_it():
    with local_cluster() as cluster, distributed.Client(cluster) as c, executor(client=c) as ex:
        value = np.arange(1000.0)
        h = ex.constant(value)
        distributed.wait(h)
        (holder,) = c.who_has(h)[h.key]
        pid = c.run(os.getpid, workers=[holder])[holder]
        os.kill(pid, signal.SIGKILL)
        total = ex.gather([ex.submit(np.sum, h)])[0]
    assert total == value.sum()


def test_scheduler_lost_mid_run_is_one_line_and_leaves_no_partial_file(inputs, tmp_path, capsys):
    tmp, paths = inputs
    marks = tmp_path / "marks"
    marks.mkdir()
    out = tmp / "out"
    with cli_cluster(tmp_path, lambda c: c.run(slow_reads, str(marks), 0.03)) as (address, sched):
        th, result = command_in_thread(
            ["encode", *paths, "-m", tmp / "model.h5", "-o", f"{out}/", "--scheduler", address]
        )
        _wait_for_mark(marks)
        sched.send_signal(signal.SIGKILL)
        th.join(timeout=60)
    assert result.get("code") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"sparsebtf: error: lost the Dask scheduler at {address}")
    for f in out.iterdir() if out.exists() else []:  # only whole files: BTFs done before
        assert f.name.endswith(".coded.h5") and load_coded(f).n_points > 0


def test_environment_names_the_scheduler(client, model, monkeypatch, capsys):
    monkeypatch.setenv("SPARSEBTF_SCHEDULER", client.scheduler.address)
    btf = smooth_btf(5)
    got = encode(btf, model, tau=(16, 4, 4), progress=False)
    assert f"Dask scheduler {client.scheduler.address}" in capsys.readouterr().err
    assert_same_codes(got, encode(btf, model, tau=(16, 4, 4), progress=False,
                                  client=InProcess()))  # fmt: skip
