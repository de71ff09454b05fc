"""The cache of synthetic materials (issue 33, item 7): large writes announced, ``sparsebtf
cache`` lists, sizes and clears it, ``SPARSEBTF_CACHE_MAX`` caps it by least recent use."""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path

import pytest

import sparsebtf.data.cache as cache_mod
from sparsebtf.cli.main import main
from sparsebtf.data.cache import clear, enforce_cap, entries, parse_size
from sparsebtf.data.synth import cache_path, cached
from sparsebtf.errors import SparseBTFError

TINY = {"size": 4, "directions": "tiny7"}


@pytest.fixture
def folder(tmp_path: Path, monkeypatch) -> Path:
    d = tmp_path / "cache"
    monkeypatch.setenv("SPARSEBTF_CACHE", str(d))
    monkeypatch.delenv("SPARSEBTF_CACHE_MAX", raising=False)
    return d


def _make(material: str, seed: int, age: float = 0.0) -> Path:
    """A tiny cached material, last used ``age`` seconds ago."""
    cached(material, seed=seed, **TINY)
    p = cache_path(material, seed=seed, **TINY)
    if age:
        t = p.stat().st_mtime - age
        os.utime(p, (t, t))
    return p


def _cli(capsys, *argv: str) -> dict:
    assert main(["cache", *argv]) == 0
    return json.loads(capsys.readouterr().out)


def test_sizes_parse_in_every_unit() -> None:
    assert parse_size("2GB") == 2 * 10**9
    assert parse_size("2GiB") == parse_size("2g") == 2 * 2**30
    assert parse_size("500 MiB") == 500 * 2**20
    assert parse_size("1.5T") == int(1.5 * 2**40)
    assert parse_size("123") == 123 and parse_size("0") == 0
    for bad in ("", "2XB", "-1GB", "GB", "1e9"):
        with pytest.raises(SparseBTFError, match="SPARSEBTF_CACHE_MAX="):
            parse_size(bad)


def test_list_size_and_clear(folder: Path, capsys) -> None:
    felt, stone = _make("felt", 0, age=100), _make("stone", 1)
    (folder / "notes.txt").write_text("not ours")  # a foreign file: never listed nor removed
    listed = _cli(capsys, "list", "--json")
    assert [f["name"] for f in listed["files"]] == [felt.name, stone.name]  # LRU first
    sizes = [felt.stat().st_size, stone.stat().st_size]
    assert [f["bytes"] for f in listed["files"]] == sizes
    assert listed["total_bytes"] == sum(sizes) and listed["folder"] == str(folder)
    assert _cli(capsys, "--json", "size") == {
        "folder": str(folder),
        "entries": 2,
        "total_bytes": sum(sizes),
        "cap_bytes": None,
    }
    assert main(["cache"]) == 0  # the table
    out = capsys.readouterr().out
    assert f"{folder}: 2 entries" in out and felt.name in out and "notes.txt" not in out
    gone = _cli(capsys, "clear", "stone", "--json")
    assert [f["name"] for f in gone["removed"]] == [stone.name] and gone["entries"] == 1
    assert not stone.exists() and felt.exists()
    _make("stone", 1)
    gone = _cli(capsys, "clear", "synth-*", "--json")
    assert len(gone["removed"]) == 2 and gone["total_bytes"] == 0
    assert sorted(p.name for p in folder.iterdir()) == ["notes.txt"]
    assert main(["cache", "clear"]) == 0
    assert "removed 0 entries" in capsys.readouterr().out


def test_cap_evicts_least_recently_used_never_the_new_one(folder, monkeypatch) -> None:
    monkeypatch.setattr(cache_mod, "_IN_USE", set())
    old, mid = _make("felt", 0, age=300), _make("felt", 1, age=200)
    one = old.stat().st_size
    monkeypatch.setenv("SPARSEBTF_CACHE_MAX", str(2 * one + one // 2))  # room for two
    cached("felt", seed=1, **TINY)  # reused: now the more recent of the two
    assert mid.stat().st_mtime > old.stat().st_mtime
    cache_mod._IN_USE.clear()  # as if other processes had used them: only their age counts
    with pytest.warns(UserWarning, match=r"capped at .*removed 1 least recently used.*felt"):
        new = _make("felt", 2)
    assert not old.exists() and mid.exists() and new.exists()
    # A cap below one entry: what this process uses stays, and a note says so ...
    cached("felt", seed=1, **TINY)
    monkeypatch.setenv("SPARSEBTF_CACHE_MAX", "0")
    with pytest.warns(UserWarning, match="in use by this process"):
        assert enforce_cap(new) == []
    # ... a later process keeps only the entry it has just written.
    cache_mod._IN_USE.clear()
    with pytest.warns(UserWarning, match="capped at 0 B.*removed 1"):
        assert [e.path for e in enforce_cap(new)] == [mid]
    assert [e.path for e in entries()] == [new]


def test_a_bad_cap_is_one_line_before_any_work(folder, monkeypatch, capsys) -> None:
    monkeypatch.setenv("SPARSEBTF_CACHE_MAX", "lots")
    assert main(["info", "synth:felt:4:0:tiny7", "--no-scan"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["sparsebtf: error: SPARSEBTF_CACHE_MAX='lots': expected a size such as 2GB, "
                   "500MiB, 1.5G or a number of bytes"]  # fmt: skip
    assert not folder.exists() or entries() == []


def test_large_writes_are_announced_in_one_note(folder, monkeypatch, capsys) -> None:
    monkeypatch.setattr(cache_mod, "NOTE_BYTES", 1)  # every write counts as large here
    monkeypatch.setattr(cache_mod, "_HINTED", set())
    assert main(["info", "synth:felt:4:0:tiny7", "--no-scan"]) == 0
    notes = [ln for ln in capsys.readouterr().err.splitlines() if ln]
    path = cache_path("felt", **TINY)
    assert len(notes) == 1 and notes[0].startswith(f"sparsebtf: note: caching {path.name} (")
    assert f"in {folder}" in notes[0] and "'sparsebtf cache'" in notes[0]
    assert "SPARSEBTF_CACHE_MAX" in notes[0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # reused: no note
        cached("felt", **TINY)
    # a second large write in this process: the note without the hint
    with pytest.warns(UserWarning) as notes:
        cached("felt", seed=2, **TINY)
    text = str(notes[0].message)
    assert text.startswith("caching ") and "'sparsebtf cache'" not in text
    monkeypatch.setattr(cache_mod, "NOTE_BYTES", path.stat().st_size * 10)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # small: no note
        cached("felt", seed=3, **TINY)


def test_clear_by_pattern_in_the_library(folder) -> None:
    a, b = _make("felt", 0), _make("stone", 0)
    assert [e.path for e in clear(["felt"])] == [a]
    assert b.exists() and [e.path for e in clear()] == [b]
