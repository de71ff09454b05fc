"""``encode`` says its coefficient counts as totals over the points, with τ per point beside
them (issue 33, item 7: ``--tau 32,8,8`` on 4 points read "coefficients Y 128", taken for τ)."""

from __future__ import annotations

from pathlib import Path

import pytest

from sparsebtf.cli.main import main
from sparsebtf.fuzzing import build_corpus
from sparsebtf.storage import load_coded


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("tau_text")
    build_corpus(folder)
    return folder


def test_totals_and_tau_per_point_are_told_apart(corpus: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "c.h5"
    assert main(["encode", str(corpus / "dense.h5"), "-m", str(corpus / "model.h5"), "-o",
                 str(out), "--tau", "4,2,2", "--eps", "0"]) == 0  # fmt: skip
    line = capsys.readouterr().out.splitlines()[0]
    coded = load_coded(out)
    n = coded.n_points
    total = {ch: c.nnz for ch, c in coded.codes.items()}
    assert total == {ch: n * t for ch, t in (("Y", 4), ("U", 2), ("V", 2))}  # ε = 0: all of τ
    want = (f"coefficients Y {total['Y']}, U {total['U']}, V {total['V']} over all {n} points "
            "(per point: τ Y 4, U 2, V 2, mean Y 4, U 2, V 2)")  # fmt: skip
    assert want in line, line
