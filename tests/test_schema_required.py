"""A file that says schema 3 carries everything schema 3 defines (issue 33, item 8): a missing
``stats/bound`` (or any field with a fallback for older files) is one clear line in every
reader, never an unclamped decode with exit 0."""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np
import pytest

from sparsebtf.cli.main import main
from sparsebtf.errors import FileFormatError
from sparsebtf.fuzzing import build_corpus
from sparsebtf.runtime import RuntimeBTF
from sparsebtf.storage import load_coded, save_coded
from sparsebtf.storage.coded_schema import REQUIRED_SINCE

# Fields a schema-3 file may leave out: the tie rank of codes already in the magnitude order.
OPTIONAL = {"codes/*/rank"}


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("required")
    build_corpus(folder)
    return folder


def _without(corpus: Path, tmp_path: Path, field: str, name: str = "coded.h5") -> Path:
    """A copy of the corpus file with ``field`` ("group/dataset" or "group@attribute") deleted."""
    p = tmp_path / f"cut_{name}"
    shutil.copy(corpus / name, p)
    with h5py.File(p, "r+") as f:
        if "@" in field:
            group, attr = field.split("@")
            del f[group or "/"].attrs[attr]
        else:
            del f[field]
    return p


def _fields(path: Path) -> list[str]:
    """Every attribute and dataset of a coded file, as "group@attr" / "group/dataset"."""
    out: list[str] = []
    with h5py.File(path, "r") as f:
        out += [f"@{a}" for a in f.attrs if a not in ("format", "schema_version")]

        def visit(name: str, obj: object) -> None:
            if isinstance(obj, h5py.Dataset):
                out.append(name)
            out.extend(f"{name}@{a}" for a in obj.attrs)  # type: ignore[attr-defined]

        f.visititems(visit)
    return out


def _pattern(field: str) -> str:
    return field.replace("codes/Y", "codes/*").replace("codes/U", "codes/*").replace(
        "codes/V", "codes/*")  # fmt: skip


def test_missing_bound_is_refused_by_every_reader(corpus: Path, tmp_path: Path, capsys) -> None:
    p = _without(corpus, tmp_path, "stats/bound")
    with pytest.raises(FileFormatError) as e:
        load_coded(p)
    msg = str(e.value)
    assert str(p) in msg and "'bound'" in msg and "schema 3" in msg and "\n" not in msg
    with pytest.raises(FileFormatError, match="missing dataset 'bound'"):
        RuntimeBTF.from_file(p, corpus / "model.h5")
    model = corpus / "model.h5"
    out = tmp_path / "out.h5"
    for argv in (["decode", p, "-m", model, "-o", out],
                 ["eval", p, "-m", model, "--reference", corpus / "dense.h5"],
                 ["lookup", p, "-m", model, "--texel", "0,0", "--light", "0", "--view", "0"],
                 ["info", p], ["convert", p, "-o", out]):  # fmt: skip
        capsys.readouterr()
        assert main([str(a) for a in argv]) != 0, argv
        err = [ln for ln in capsys.readouterr().err.splitlines() if ln]
        assert len(err) == 1 and "missing dataset 'bound'" in err[0], (argv, err)
        assert "schema 3" in err[0]
        assert not out.exists()


# The schema-3 fields on a schema-3 file; the schema-4 ones (each patch size's channel groups)
# on adaptive files: tests/test_field_fuzz.py::test_channel_counts_are_required_and_checked.
@pytest.mark.parametrize("req", [r for r in REQUIRED_SINCE if r.since == 3],
                         ids=lambda r: f"{r.group}:{r.name}")
def test_every_field_of_the_table_is_refused_when_missing(corpus, tmp_path, req) -> None:
    group = req.group.replace("*", "Y")
    field = f"{group}@{req.name}" if req.kind == "attribute" else f"{group}/{req.name}"
    p = _without(corpus, tmp_path, field)
    with pytest.raises(FileFormatError, match=rf"missing {req.kind} '{req.name}'.*schema 3"):
        load_coded(p)


def test_no_field_of_a_schema3_file_may_go_missing(corpus: Path, tmp_path: Path) -> None:
    """Beyond the table: deleting any one attribute or dataset is refused (the table plus the
    readers' own demands leave no fallback), apart from the truly optional ones."""
    accepted = []
    for field in _fields(corpus / "coded.h5"):
        p = _without(corpus, tmp_path, field)
        try:
            load_coded(p)
        except FileFormatError:
            continue
        accepted.append(_pattern(field))
    assert set(accepted) <= OPTIONAL, accepted


def test_older_schemas_keep_their_fallbacks(corpus: Path, tmp_path: Path) -> None:
    for name in ("coded_v2.h5", "coded_v1.h5"):
        with h5py.File(corpus / name, "r") as f:
            if "bound" not in f["stats"]:
                continue
        p = _without(corpus, tmp_path, "stats/bound", name)
        assert load_coded(p).stats.bound is None


def test_a_file_without_a_bound_says_so_and_reads_back(corpus, tmp_path, capsys) -> None:
    """Statistics without a bound (a release import) are written with ``stats@clamp = "none"``;
    that file reads, decodes unclamped and ``info`` says why; the marker with a bound, or
    another value, is refused."""
    coded = load_coded(corpus / "coded.h5")
    free = replace(coded, stats=replace(coded.stats, bound=None))
    p = tmp_path / "free.h5"
    save_coded(free, p)
    with h5py.File(p, "r") as f:
        assert "bound" not in f["stats"] and f["stats"].attrs["clamp"] == b"none"
    assert load_coded(p).stats.bound is None
    assert main(["info", str(p), "-m", str(corpus / "model.h5"), "--json", "--no-scan"]) == 0
    text = capsys.readouterr().out
    assert "says its statistics have none" in text and "older file" not in text
    save_coded(free, tmp_path / "v2.h5", schema=2)
    with h5py.File(tmp_path / "v2.h5", "r") as f:
        assert "clamp" not in f["stats"].attrs  # the schema-2 layout is unchanged
    bad = tmp_path / "both.h5"
    shutil.copy(corpus / "coded.h5", bad)
    with h5py.File(bad, "r+") as f:
        f["stats"].attrs["clamp"] = np.bytes_(b"none")
    with pytest.raises(FileFormatError, match=r"'clamp'.*without a 'bound'"):
        load_coded(bad)
    with h5py.File(p, "r+") as f:
        f["stats"].attrs["clamp"] = np.bytes_(b"off")
    with pytest.raises(FileFormatError, match="missing dataset 'bound'"):
        load_coded(p)
