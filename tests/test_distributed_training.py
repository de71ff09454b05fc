"""Training on a real Dask cluster (worker processes on 127.0.0.1, started here) and resuming.

Small shapes: three 12×12-texel BTFs of 13 directions, 4×4 patches (27 training points per
channel, 4 partitions), K = 3.
"""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest

from sparsebtf.cli.main import main
from sparsebtf.codec import train
from sparsebtf.data.dense_file import write_dense
from sparsebtf.execution import PairwiseSum, _pairwise_sum
from sparsebtf.storage import load_model

from ._cluster import cli_cluster, command_in_thread, wait_for
from ._workers import slow_coding
from .conftest import smooth_btf

distributed = pytest.importorskip("distributed")

OPTIONS = ["--patch", "4", "--dicts", "3", "--tau-train", "16,4,4", "--sample", "1",
           "--iters", "3", "--candidates", "1", "--full-pass-every", "2"]  # fmt: skip
KW = dict(n_dictionaries=3, tau_train=(16, 4, 4), patch=4, sample=1.0, max_iter=3,
          candidates=1, full_pass_every=2, progress=False)  # fmt: skip


@pytest.fixture(scope="module")
def paths(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("train-inputs")
    out = []
    for s in range(3):
        p = tmp / f"m{s}.h5"
        write_dense(p, smooth_btf(20 + s, size=12))
        out.append(str(p))
    return out


@pytest.fixture(scope="module")
def one_process(paths):
    """The reference: the whole training in this process (the default)."""
    return train(paths, **KW)


def local_cluster(n: int = 2):
    return distributed.LocalCluster(
        n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
        dashboard_address=":0", scheduler_kwargs={"dashboard": False},
    )  # fmt: skip


def assert_same_model(a, b):
    assert a.channels == b.channels
    for ch in a.channels:
        for x, y in zip(a.dictionaries[ch], b.dictionaries[ch], strict=True):
            assert np.array_equal(x, y), (ch, float(np.abs(x - y).max()))
        for f in ("objective", "passes", "membership_counts", "n_iter"):
            assert a.training[ch][f] == b.training[ch][f], (ch, f)


def test_streamed_pairwise_sum_pairs_like_the_tree():
    def add(x, y):
        return f"({x}+{y})"

    for n in range(1, 40):
        acc = PairwiseSum(add)
        for i in range(n):
            acc.add(str(i))
        assert acc.total() == _pairwise_sum([str(i) for i in range(n)], add)


def test_cluster_training_equals_one_process_training(paths, one_process, tmp_path, capsys):
    assert one_process.training["Y"]["passes"] == ["full", "partial", "full", "full"]
    out = tmp_path / "cluster.h5"
    assert main(["train", *paths, "-o", str(out), *OPTIONS, "--workers", "2"]) == 0
    assert "local Dask cluster" in capsys.readouterr().err
    assert_same_model(load_model(out), one_process)
    assert not (tmp_path / "cluster.h5.checkpoint").exists()  # removed once the model is written


def test_worker_killed_mid_training_changes_nothing(paths, one_process, tmp_path):
    out = tmp_path / "model.h5"
    marks = tmp_path / "marks"
    marks.mkdir()
    with local_cluster() as cluster, distributed.Client(cluster) as c:
        c.run(slow_coding, str(marks), 0.05)
        with distributed.get_task_stream(client=c) as ts:
            th, result = command_in_thread(
                ["train", *paths, "-o", out, *OPTIONS, "--scheduler", cluster.scheduler_address]
            )
            # After the first iteration of Y: every worker holds partitions and codes.
            wait_for(tmp_path / "model.h5.checkpoint" / "train_Y.npz")
            assert th.is_alive()
            victim = int(next(iter(marks.iterdir())).name)
            os.kill(victim, signal.SIGKILL)
            th.join(timeout=180)
        assert result.get("code") == 0
        assert victim not in c.run(os.getpid).values()  # the nanny started a new process
    # Each channel's 4 partitions were loaded, and again any held only by the victim (Dask
    # may also have copied some to the other worker, which then need no reload).
    assert sum("load_partition" in r["key"] for r in ts.data) >= 3 * 4
    assert_same_model(load_model(out), one_process)


def test_scheduler_lost_mid_training_then_resume_equals_one_run(paths, one_process, tmp_path,
                                                               capsys):  # fmt: skip
    marks = tmp_path / "marks"
    marks.mkdir()
    out = tmp_path / "model.h5"
    ck = tmp_path / "model.h5.checkpoint"
    with cli_cluster(tmp_path, lambda c: c.run(slow_coding, str(marks), 0.05)) as (address, sched):
        th, result = command_in_thread(["train", *paths, "-o", out, *OPTIONS, "--scheduler",
                                        address])  # fmt: skip
        wait_for(ck / "train_Y.npz")
        sched.send_signal(signal.SIGKILL)
        th.join(timeout=90)
    assert result.get("code") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"sparsebtf: error: lost the Dask scheduler at {address}")
    assert "--resume" in err[-1]
    assert not out.exists() and not list(tmp_path.glob("*.tmp*"))  # no half-written model
    assert (ck / "train_Y.npz").exists()
    # Start again by accident: refused. Resume (in this process): the uninterrupted result.
    assert main(["train", *paths, "-o", str(out), *OPTIONS]) == 2
    assert "add --resume" in capsys.readouterr().err
    assert main(["train", *paths, "-o", str(out), *OPTIONS, "--resume"]) == 0
    assert_same_model(load_model(out), one_process)
    assert not ck.exists()


def test_resume_checks(paths, tmp_path, capsys):
    out = tmp_path / "m.h5"
    assert main(["train", paths[0], "-o", str(out), *OPTIONS, "--resume"]) == 2
    assert "no checkpoint in" in capsys.readouterr().err
    ck = tmp_path / "ck"
    assert main(["train", paths[0], "-o", str(out), *OPTIONS, "--iters", "1",
                 "--checkpoint-dir", str(ck)]) == 0  # fmt: skip
    assert (ck / "train_Y.npz").exists()  # a folder the user named is kept
    capsys.readouterr()
    code = main(["train", paths[0], "-o", str(tmp_path / "m2.h5"), *OPTIONS, "--dicts", "2",
                 "--checkpoint-dir", str(ck), "--resume"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert "other training parameters or data (K: 3 in the checkpoint, 2 now)" in err
    code = main(["train", paths[1], "-o", str(tmp_path / "m2.h5"), *OPTIONS,
                 "--checkpoint-dir", str(ck), "--resume"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and "data:" in err and err.count("\n") == 1


def test_bench_quality_passes_the_cluster_to_its_runs(monkeypatch, tmp_path):
    import sparsebtf.evaluation.runner as runner

    seen = {}

    def fake_run(out, cfg, **kw):
        seen.update(kw)
        return {"summary": {}}

    monkeypatch.setattr(runner, "run_quality", fake_run)
    assert main(["bench", "quality", "--quick", "--out", str(tmp_path / "q"),
                 "--scheduler", "tcp://127.0.0.1:8786"]) == 0  # fmt: skip
    assert seen["scheduler"] == "tcp://127.0.0.1:8786" and seen["workers"] is None
    # and the runner hands its executor to the methods, which pass it to every training
    # and encoding call
    import inspect

    from sparsebtf.evaluation.methods import sparse

    assert "executor=self.ex" in inspect.getsource(runner._QualityRun.fit)
    src = inspect.getsource(sparse)
    calls = src.count(" train(") + src.count("encode_levels(") + src.count("encode_rate_levels(")
    assert calls == 3
    assert src.count("client=context.executor") + src.count("client=ctx.executor") == calls
