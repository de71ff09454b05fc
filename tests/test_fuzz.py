"""Mutation fuzzing of every reader (seeded, small): a damaged file is either read or refused
with a project error, never a traceback from a library, a hang or a crash.

Each case is a mutated copy of a small valid file from our own writers
(:mod:`sparsebtf.fuzzing`); ``benchmarks/fuzz.py`` runs thousands of the same cases, each in a
subprocess with a memory cap and a time limit.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sparsebtf.fuzzing import READERS, build_corpus, exercise, run_case

#: Cases per reader: the HDF5 readers pay for a forked watchdog per new file.
CASES = {"ubo2014": 300, "ubo2003": 300, "release": 300, "dense": 120, "model": 120, "coded": 120}


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, list[Path]], Path]:
    folder = tmp_path_factory.mktemp("corpus")
    return build_corpus(folder), folder


def test_corpus_files_are_read(corpus: tuple[dict[str, list[Path]], Path]) -> None:
    files, folder = corpus
    assert set(files) == set(READERS)
    for reader, paths in files.items():
        assert paths
        for p in paths:
            assert p.stat().st_size < 2**20  # every fuzz input stays under 1 MB
            exercise(reader, p, folder)  # the unmutated seeds are valid


@pytest.mark.parametrize("reader", READERS)
def test_reader_fails_cleanly(
    reader: str, corpus: tuple[dict[str, list[Path]], Path], tmp_path: Path
) -> None:
    files, folder = corpus
    outcomes: dict[str, int] = {}

    @settings(
        max_examples=CASES[reader],
        derandomize=True,
        database=None,
        deadline=None,
        suppress_health_check=list(HealthCheck),
    )
    @given(seed=st.integers(0, 2**31 - 1))
    def case(seed: int) -> None:
        # Anything but acceptance or a SparseBTFError propagates and fails the test, with
        # the seed that replays it: run_case(corpus, reader, seed, ...).
        result = run_case(files, reader, seed, tmp_path / "case", folder)
        outcomes[result] = outcomes.get(result, 0) + 1

    case()
    # The mutations reach the readers' checks (not only, say, a magic-number test).
    assert sum(outcomes.values()) >= CASES[reader] // 2  # hypothesis ran the cases
    assert outcomes.get("error", 0) > 0


# --------------------------------------------------------------------------- semantic fuzzing

#: Semantic cases per file kind here (benchmarks/fuzz.py --semantic runs thousands).
SEMANTIC_CASES = 80


@pytest.fixture(scope="module")
def semantic_corpus(tmp_path_factory: pytest.TempPathFactory) -> dict:
    from sparsebtf.fuzzing import build_semantic_corpus

    return build_semantic_corpus(tmp_path_factory.mktemp("semantic"))


@pytest.mark.parametrize("kind", ["ubo2014", "dense", "model", "coded", "release", "checkpoint"])
def test_semantic_no_silent_wrong_output(
    kind: str, semantic_corpus: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """One field of a valid file set to 0, −1, huge, NaN, ±inf, a duplicate, a permutation …:
    refused with a project error when the format's rules are broken, accepted with finite
    results (the unmutated file's, for unused fields) when they hold."""
    from sparsebtf.fuzzing import run_semantic_case

    monkeypatch.setenv("SPARSEBTF_HDF5_GUARD", "0")  # in process: no watchdog fork per case
    outcomes: dict[str, int] = {}
    for seed in range(SEMANTIC_CASES):
        res = run_semantic_case(semantic_corpus, kind, seed, tmp_path)
        assert res["outcome"] in ("rejected", "correct"), res  # replay: run_semantic_case(...)
        outcomes[res["outcome"]] = outcomes.get(res["outcome"], 0) + 1
    # Both sides of the rules are reached: impossible values and changes that stay valid.
    assert outcomes.get("rejected", 0) >= SEMANTIC_CASES // 5
    assert outcomes.get("correct", 0) >= 1


def test_semantic_oracle_catches_a_missing_check(
    semantic_corpus: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The fuzz can fail: with the direction-table and statistics checks switched off, cases
    that break the rules are accepted and counted as silent wrong outputs."""
    import sparsebtf._semantic as semantic
    import sparsebtf.data.dense_file as dense_file
    from sparsebtf.fuzzing import run_semantic_case

    monkeypatch.setenv("SPARSEBTF_HDF5_GUARD", "0")
    monkeypatch.setattr(dense_file, "check_directions", lambda xyz, where: None)
    monkeypatch.setattr(semantic, "check_statistics", lambda stats, where: None)
    outcomes = [run_semantic_case(semantic_corpus, kind, seed, tmp_path)["outcome"]
                for kind in ("dense", "coded") for seed in range(60)]  # fmt: skip
    assert outcomes.count("silent_wrong") >= 5
