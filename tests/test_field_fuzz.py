"""Every attribute a reader relies on is required and checked against the data (issue 47,
item 2): the named cases one by one, and an exhaustive field fuzz (every dataset and attribute
of schema-3 to 8 coded files and a model of several training levels, deleted, −1, 2^40, NaN, one
element fewer or more) that finds no accepted file whose output a damaged field changed."""

from __future__ import annotations

import shutil
from collections import Counter
from pathlib import Path

import h5py
import numpy as np
import pytest

from sparsebtf.errors import FileFormatError
from sparsebtf.testing.field_fuzz import (
    FIELD_FILES,
    FIELD_MUTATIONS,
    build_field_corpus,
    field_exercise,
    file_fields,
    mutate_field,
    run_field_case,
    run_field_fuzz,
)


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> dict:
    return build_field_corpus(tmp_path_factory.mktemp("field_fuzz"))


@pytest.fixture(autouse=True)
def _no_guard(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SPARSEBTF_HDF5_GUARD", "0")  # in process: no watchdog fork per case


def _refused(corpus: dict, kind: str, field: str, op: str, tmp_path: Path) -> str:
    """The one-line message of the reader's refusal of ``field`` damaged by ``op``."""
    path = tmp_path / FIELD_FILES[kind]
    shutil.copyfile(corpus["dir"] / FIELD_FILES[kind], path)
    mutate_field(path, field, op)
    with pytest.raises(FileFormatError) as e:
        field_exercise(kind, path, corpus)
    msg = str(e.value)
    assert "\n" not in msg and str(path) in msg, msg
    return msg


# The channel counts of a coded file, each in schema 3 (codes/<CH>) and 4 (sizes/<s>/<CH>).
@pytest.mark.parametrize("op", ["delete", "minus_one", "huge"])
@pytest.mark.parametrize("name", ["n_points", "nnz", "location_bytes", "n_dictionaries"])
@pytest.mark.parametrize(("kind", "group"), [("coded3", "codes/U"), ("coded4", "sizes/2/Y")])
def test_channel_counts_are_required_and_checked(corpus, tmp_path, kind, group, name, op):
    msg = _refused(corpus, kind, f"{group}@{name}", op, tmp_path)
    assert f"'{name}'" in msg and group in msg, msg


@pytest.mark.parametrize("op", ["nan", "shorter", "longer", "huge"])
@pytest.mark.parametrize("field", ["lights/phi", "views/theta"])
@pytest.mark.parametrize("kind", ["coded3", "coded4", "model"])
def test_damaged_angle_tables_are_refused(corpus, tmp_path, kind, field, op):
    """θ/φ are checked against ``xyz`` (entry 0 set to 2^40 or NaN, one entry fewer or
    more). Direction 0 of the table is the pole, whose azimuth is free: φ = 2^40 there is no
    damage (the field fuzz finds it accepted with the same output)."""
    if field.endswith("phi") and op == "huge":
        pytest.skip("φ of the pole (entry 0) is any angle: no damage")
    msg = _refused(corpus, kind, field, op, tmp_path)
    assert field in msg, msg


@pytest.mark.parametrize("name", ["params_json", "channels", "provenance_json",
                                  "training_json", "library_version"])  # fmt: skip
def test_model_root_attributes_are_required(corpus, tmp_path, name):
    """A model of several training levels without ``params_json`` (or another root
    attribute) is refused; it never loads with its τ_l levels lost."""
    assert corpus["originals"]["model"]  # the seed has τ_l levels: see the next assertion
    from sparsebtf.storage import load_model

    levels = load_model(corpus["dir"] / FIELD_FILES["model"])
    assert len(set(levels.dictionary_taus("Y"))) == 2
    msg = _refused(corpus, "model", f"@{name}", "delete", tmp_path)
    assert f"'{name}'" in msg, msg


def test_field_fuzz_finds_no_silent_wrong_output(corpus, tmp_path):
    """Every field of every seed, each mutation: refused in one line, or accepted with the
    undamaged file's output exactly (a statistic of −1 is the one legal value change)."""
    results = run_field_fuzz(corpus, tmp_path)
    bad = [r for r in results if r["outcome"] in ("silent_wrong", "traceback")]
    assert not bad, bad[:5]
    counts = Counter(r["outcome"] for r in results)
    n_fields = sum(len(file_fields(corpus["dir"] / f)) for f in FIELD_FILES.values())
    assert len(results) == n_fields * len(FIELD_MUTATIONS)
    assert counts["rejected"] > len(results) // 2, counts  # the damage is mostly refused
    refused = [r for r in results if r["outcome"] == "rejected"]
    assert all("\n" not in r["message"] for r in refused)


def test_field_fuzz_catches_a_missing_check(corpus, tmp_path, monkeypatch):
    """The fuzz can fail: with the model's required root attributes unchecked, a model whose
    ``params_json`` is deleted loads without its τ_l levels, a silent wrong output."""
    import sparsebtf.storage.model_file as model_file

    monkeypatch.setattr(model_file, "_check_root", lambda f, schema, where: None)
    res = run_field_case(corpus, "model", "@params_json", "delete", tmp_path)
    assert res["outcome"] == "silent_wrong", res


@pytest.mark.parametrize("field", ["views/phi", "lights/theta"])
def test_a_wrong_finite_angle_is_refused(corpus, tmp_path, field):
    """An in-range angle that disagrees with ``xyz`` (off the pole) is damage too."""
    path = tmp_path / FIELD_FILES["coded3"]
    shutil.copyfile(corpus["dir"] / FIELD_FILES["coded3"], path)
    with h5py.File(path, "r+") as f:
        a = f[field][()]
        a[1] += 0.25  # radians
        f[field][...] = a
        assert abs(float(np.cos(f["views/theta"][1]))) < 1  # direction 1 is off the pole
    with pytest.raises(FileFormatError, match=rf"{field}: direction 1 has"):
        field_exercise("coded3", path, corpus)
