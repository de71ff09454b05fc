"""Several τ_l, learned τ_l and pre-clustering on a real Dask cluster (worker processes on
127.0.0.1): the same models as in this process (shapes of test_distributed_training.py)."""

from __future__ import annotations

import pytest

from sparsebtf.codec import train
from sparsebtf.data.dense_file import write_dense

from .conftest import smooth_btf
from .test_distributed_training import assert_same_model, local_cluster

distributed = pytest.importorskip("distributed")

BASE = dict(patch=4, sample=1.0, max_iter=2, candidates=1, full_pass_every=2, progress=False)
CASES = [
    dict(n_dictionaries=4, tau_train="8,2,2/16,4,4", init="preclustered"),
    dict(n_dictionaries=2, tau_train="learn:8,2,2/16,4,4"),
]


@pytest.fixture(scope="module")
def paths(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("levels-inputs")
    for s in range(3):
        write_dense(tmp / f"m{s}.h5", smooth_btf(20 + s, size=12))
    return [str(tmp / f"m{s}.h5") for s in range(3)]


def test_cluster_equals_one_process(paths):
    with local_cluster() as cluster, distributed.Client(cluster) as c:
        for case in CASES:
            here = train(paths, **BASE, **case)
            there = train(paths, client=c, **BASE, **case)
            assert_same_model(there, here)
            assert there.params == here.params
