"""The command line speaks one language (issue 20, item 4, and the output defects of item 3):
``--version``, one meaning per option name, τ fractions wherever τ is taken, bounded numbers,
clear errors for values that start with '-', sizes announced before large writes, real
``.btf`` output, ``| head`` exiting 0, the user's umask, stale temporaries removed, notes
instead of raw warnings, readable tables and one PSNR. Tiny shapes: 13 directions, 8x8 texels.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

import sparsebtf
from sparsebtf.cli.main import main

SRC = Path(sparsebtf.__file__).resolve().parents[1]


def run(argv, capsys):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def cli(argv, **kw) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(SRC), "SPARSEBTF_PROGRESS": "0"}
    return subprocess.run([sys.executable, "-m", "sparsebtf.cli.main", *map(str, argv)],
                          env=env, capture_output=True, text=True, timeout=120, **kw)  # fmt: skip


# --------------------------------------------------------------------------- the parser


def test_version_prints_the_library_version(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"sparsebtf {sparsebtf.library_version()}"


def test_value_starting_with_dash_gets_a_clear_message(capsys):
    with pytest.raises(SystemExit) as e:
        main(["convert", "synth:stone:8", "-o", "x.h5", "--crop", "-10:10,0:10"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--crop: expected one argument" in err
    assert "must be attached: --crop=VALUE" in err


def test_attached_dash_value_reaches_the_range_check(tmp_path, capsys):
    code, _, err = run(["convert", "synth:stone:8:0:tiny13", "-o", tmp_path / "x.h5",
                        "--crop=-10:10,0:10"], capsys)  # fmt: skip
    assert code == 2
    assert err.count("\n") == 1 and "--crop -10:10,0:10: rows R0:R1" in err


# --------------------------------------------------------------------------- pipes, folders


def test_head_closing_the_pipe_exits_0():
    # `info … | head -1`: the reader goes away after one line; the pipeline's status is ours.
    env = {**os.environ, "PYTHONPATH": str(SRC), "SPARSEBTF_PROGRESS": "0"}
    proc = subprocess.run(
        f"{sys.executable} -m sparsebtf.cli.main info synth:stone:8:0:tiny13 --no-scan | head -1"
        "; echo \"status ${PIPESTATUS[0]}\"",
        shell=True, executable="/bin/bash", env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 2 and lines[-1] == "status 0", proc.stdout + proc.stderr
    assert "Error" not in proc.stderr and "Traceback" not in proc.stderr


def test_broken_pipe_in_process_returns_0(monkeypatch, capsys):
    class Gone:
        def write(self, text):
            raise BrokenPipeError

        def flush(self):
            raise BrokenPipeError

        def fileno(self):
            return sys.__stdout__.fileno()

    # main() points the real stdout at /dev/null afterwards; keep ours.
    monkeypatch.setattr(os, "dup2", lambda *a: None)
    monkeypatch.setattr(sys, "stdout", Gone())
    assert main(["info", "synth:stone:8:0:tiny13", "--no-scan"]) == 0


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_stale_temporaries_of_any_output_are_removed_by_the_next_run(tmp_path, capsys):
    from sparsebtf._atomic import _host

    dead, host = _dead_pid(), _host()
    stale_file = tmp_path / f".other.h5.{dead}-{host}.abcd1234.part"  # another target's
    stale_dir = tmp_path / f".site.{dead}-{host}.ef_5678.part"  # a killed viewer export
    live = tmp_path / f".busy.h5.{os.getpid()}-{host}.ijkl9012.part"  # a live writer's
    foreign = tmp_path / f".x.h5.{dead}-00000000.mnop3456.part"  # another host's, recent
    mine = tmp_path / "notes.part"  # not our pattern
    stale_dir.mkdir()
    (stale_dir / "data.bin").write_bytes(b"partial")
    for p in (stale_file, live, foreign, mine):
        p.write_bytes(b"partial")
    code, _, err = run(["convert", "synth:stone:8:0:tiny13", "-o", tmp_path / "new.h5"], capsys)
    assert code == 0, err
    assert not stale_file.exists() and not stale_dir.exists()
    assert live.exists() and foreign.exists() and mine.exists()


def test_old_temporaries_from_another_host_are_removed(tmp_path):
    from sparsebtf._atomic import FOREIGN_STALE_SECONDS, remove_stale_parts

    old = tmp_path / ".x.h5.123-00000000.abcd1234.part"
    old.write_bytes(b"partial")
    t = old.stat().st_mtime - FOREIGN_STALE_SECONDS - 60
    os.utime(old, (t, t))
    assert remove_stale_parts(tmp_path / "y.h5") == [old]


def test_view_export_folder_follows_the_umask(tmp_path):
    from sparsebtf.rendering.viewer import export

    class Bundle:
        def files(self):
            return {"index.html": b"<html></html>"}

    previous = os.umask(0o022)
    try:
        out = export(Bundle(), tmp_path / "site")
    finally:
        os.umask(previous)
    assert out.stat().st_mode & 0o777 == 0o755
    assert [p.name for p in tmp_path.iterdir()] == ["site"]
