"""Every output path and extension is checked before any work starts (issue 33, item 7): a coded
file is not written under a ``.btf`` name, an output under ``/proc`` is refused before the
encode, in one line, with no output or checkpoint folder left behind."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

import sparsebtf.codec
from sparsebtf.cli._args import OUTPUT_FORMATS, output_format
from sparsebtf.cli.main import main
from sparsebtf.errors import SparseBTFError
from sparsebtf.fuzzing import build_corpus


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("outputs")
    build_corpus(folder)
    return folder


@pytest.fixture
def no_encoding(monkeypatch):
    """Fail the test if any encoding starts."""

    def refuse(*args, **kwargs):
        raise AssertionError("the encode started before its output was checked")

    monkeypatch.setattr(sparsebtf.codec, "encode_many", refuse)


def one_line(capsys) -> str:
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln]
    assert len(lines) == 1 and lines[0].startswith("sparsebtf: error: "), lines
    return lines[0]


def test_encode_refuses_a_coded_file_under_a_btf_name(corpus, tmp_path, capsys, no_encoding):
    out = tmp_path / "x.coded.btf"
    argv = ["encode", str(corpus / "dense.h5"), "-m", str(corpus / "model.h5"), "-o", str(out)]
    assert main(argv) == 2
    msg = one_line(capsys)
    assert f"-o {out}: unknown extension '.btf'" in msg and "give .h5" in msg and "DIR/" in msg
    assert list(tmp_path.iterdir()) == []  # no output, no x.coded.btf.checkpoint


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux's /proc")
def test_encode_under_proc_fails_before_any_work(corpus, tmp_path, capsys, no_encoding):
    """Root may 'write' everywhere by os.access, /proc included; the check makes a folder."""
    out = Path("/proc/nope/x.h5")
    argv = ["encode", str(corpus / "dense.h5"), "-m", str(corpus / "model.h5"), "-o", str(out)]
    assert main(argv) == 2
    msg = one_line(capsys)
    assert f"-o {out}: cannot write into /proc" in msg
    assert not out.parent.exists()
    assert not Path("/proc/nope/x.h5.checkpoint").exists()


def test_a_missing_output_folder_is_made_only_when_written(corpus, tmp_path, capsys) -> None:
    """The check leaves nothing behind (its probe folder is removed); the write makes it."""
    out = tmp_path / "new" / "deep" / "c.h5"
    argv = ["encode", str(corpus / "dense.h5"), "-m", str(corpus / "model.h5"), "-o", str(out),
            "--tau", "4"]  # fmt: skip
    assert main(argv) == 0, capsys.readouterr().err
    assert out.exists() and not (out.parent / "c.h5.checkpoint").exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".sparsebtf-probe")] == []


@pytest.mark.parametrize(
    ("argv", "flag", "want"),
    [
        (
            ["blend", "{c}", "{c}", "--alpha", "0.5", "-m", "{m}", "-o", "{t}/b.btf"],
            "-o",
            "give .h5 (a coded file is HDF5)",
        ),
        (["train", "{d}", "-o", "{t}/m.btf", "--patch", "1"], "-o", "a model file is HDF5"),
        (["import-release", "{t}", "-o", "{t}/m.mat"], "-o", "a model file is HDF5"),
        (["convert", "{c}", "--schema", "3", "-o", "{t}/c.btf"], "-o", "a coded file is HDF5"),
        (["convert", "{c}", "-o", "{t}/c.zip"], "-o", "or .btf (a UBO2014 file)"),
        (["decode", "{c}", "-m", "{m}", "-o", "{t}/x.exr"], "-o", "or .btf (a UBO2014 file)"),
        (
            ["synth", "--class", "felt", "--size", "4", "--preview", "{t}/p.jpg"],
            "--preview",
            "give .png",
        ),
        (["render", "{c}", "-m", "{m}", "-o", "{t}/r.jpg"], "-o", "give .png"),
        (
            ["render", "{c}", "-m", "{m}", "-o", "{t}/r.png", "--save-raw", "{t}/r.npy"],
            "--save-raw",
            "give .npz",
        ),
    ],
    ids=lambda v: v[0] if isinstance(v, list) else None,
)
def test_every_command_checks_its_output_names_first(corpus, tmp_path, capsys, argv, flag,
                                                     want) -> None:  # fmt: skip
    work = tmp_path / "work"
    work.mkdir()
    fill = {"c": corpus / "coded.h5", "m": corpus / "model.h5", "d": corpus / "dense.h5",
            "t": work}  # fmt: skip
    args = [a.format(**fill) for a in argv]
    assert main(args) == 2
    msg = one_line(capsys)
    assert f"{flag} {work}" in msg and "unknown extension" in msg and want in msg, msg
    assert list(work.iterdir()) == []


def test_one_rule_for_every_kind() -> None:
    assert output_format("a.H5", "coded") == "coded"
    assert output_format("a.btf", "btf") == "ubo2014"
    assert output_format(None, "png") is None
    for kind in OUTPUT_FORMATS:
        with pytest.raises(SparseBTFError, match=r"unknown extension '\.xyz'"):
            output_format("a.xyz", kind)
    with pytest.raises(SparseBTFError, match=r"unknown extension '\(none\)'"):
        output_format("noext", "model")


@pytest.mark.skipif(os.geteuid() != 0, reason="a read-only mount needs root")
def test_root_is_refused_on_a_read_only_file_system(tmp_path, capsys) -> None:
    """os.access lets root write into any folder; the probe does not."""
    import subprocess

    ro = tmp_path / "ro"
    ro.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(ro)],
                      capture_output=True).returncode != 0:  # fmt: skip
        pytest.skip("cannot mount a tmpfs here")
    try:
        assert main(["synth", "--class", "felt", "--size", "4", "-o", str(ro / "s.h5")]) == 2
        assert "cannot write into" in one_line(capsys)
    finally:
        subprocess.run(["umount", str(ro)], capture_output=True)
