"""Full disks, read-only folders and killed runs: a write that cannot finish ends in one line
("no space left on device while writing X; nothing was written"), exit 2, with the previous
output intact; a run killed with SIGKILL leaves no partial output, and its temporary file is
removed by the next write into the folder.

The full disk is a 1 MiB tmpfs when this process may mount one (root on Linux); otherwise the
commands run under a file-size limit (RLIMIT_FSIZE, the same failure through EFBIG).
"""

from __future__ import annotations

import contextlib
import os
import resource
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from sparsebtf._atomic import atomic_output, remove_stale_parts
from sparsebtf.data.dense_file import write_dense
from sparsebtf.errors import OutputError

from .conftest import smooth_btf, tiny_model

SRC = Path(__file__).resolve().parents[1] / "src"


def _mount_tmpfs(where: Path, options: str) -> bool:
    if sys.platform != "linux" or os.geteuid() != 0:
        return False
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)],
                         capture_output=True)  # fmt: skip
    return res.returncode == 0


@contextlib.contextmanager
def tmpfs(options: str) -> Iterator[Path | None]:
    where = Path(tempfile.mkdtemp(prefix="sparsebtf-tmpfs-"))
    mounted = _mount_tmpfs(where, options)
    try:
        yield where if mounted else None
    finally:
        if mounted:
            subprocess.run(["umount", str(where)], capture_output=True)
        with contextlib.suppress(OSError):
            where.rmdir()


def cli(argv: list[object], limit: int | None = None, timeout: float = 300):
    """``sparsebtf ARGV`` in a fresh process; ``limit``: RLIMIT_FSIZE in bytes."""

    def preexec() -> None:
        if limit is not None:
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write fails with EFBIG instead
            resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    env = {**os.environ, "PYTHONPATH": str(SRC), "SPARSEBTF_PROGRESS": "0"}
    return subprocess.run([sys.executable, "-m", "sparsebtf.cli.main", *map(str, argv)],
                          capture_output=True, text=True, timeout=timeout, env=env,
                          preexec_fn=preexec)  # fmt: skip


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A dense BTF, a model and a coded file on the ordinary disk."""
    from sparsebtf.codec import encode
    from sparsebtf.storage import save_coded, save_model

    d = tmp_path_factory.mktemp("inputs")
    btf = smooth_btf(7)
    write_dense(d / "btf.h5", btf)
    model = tiny_model(max_iter=1)
    save_model(model, d / "model.h5")
    coded = encode(btf, model, tau=(16, 4, 4), progress=False)
    coded.params["model_file"] = str(d / "model.h5")
    save_coded(coded, d / "coded.h5")
    return {"btf": d / "btf.h5", "model": d / "model.h5", "coded": d / "coded.h5"}


def _commands(inputs: dict[str, Path], target: Path) -> dict[str, list[object]]:
    return {
        "synth": ["synth", "--class", "stone", "--size", "16", "--directions", "tiny13", "-o",
                  target],
        "encode": ["encode", inputs["btf"], "-m", inputs["model"], "-o", target, "--tau",
                   "16,4,4"],
        "decode": ["decode", inputs["coded"], "-o", target],
        "train": ["train", inputs["btf"], "-o", target, "--dicts", "2", "--tau-train", "16,4,4",
                  "--patch", "4", "--sample", "1", "--iters", "1"],
    }  # fmt: skip


def _check_failed(res: subprocess.CompletedProcess[str], target: Path, what: str,
                  name: str = "") -> None:  # fmt: skip
    lines = [ln for ln in res.stderr.strip().splitlines() if ln]
    assert res.returncode == 2, res.stderr
    assert len(lines) == 1, res.stderr
    if name in ("train", "encode"):
        # Training and encoding fail at their first checkpoint (beside the output), before
        # hours of work; the folder made for it is removed.
        ck = target.with_name(target.name + ".checkpoint")
        first = "train_Y.npz" if name == "train" else "points_0_0_4.npz"
        assert lines[0] == (f"sparsebtf: error: {what} while writing {ck / first}; "
                            "nothing was written")  # fmt: skip
        assert not ck.exists()
    else:
        assert lines[0] == (f"sparsebtf: error: {what} while writing {target}; nothing was "
                            "written (the previous file is unchanged)")  # fmt: skip
    assert target.read_bytes() == b"previous output"
    assert [p.name for p in target.parent.iterdir() if p.name.endswith(".part")] == []


def test_full_disk_ends_in_one_line_with_previous_output_intact(inputs, tmp_path) -> None:
    """synth, encode, decode and train on a full disk (a 1 MiB tmpfs, filled but for 8 KiB),
    else under an 8 KiB file-size limit."""
    with tmpfs("size=1m,mode=0777") as disk:
        if disk is None and not hasattr(resource, "RLIMIT_FSIZE"):
            pytest.skip("neither a tmpfs mount (root on Linux) nor RLIMIT_FSIZE is available")
        target = (disk or tmp_path) / "out.h5"
        for name, argv in _commands(inputs, target).items():
            target.write_bytes(b"previous output")
            if disk is None:
                res = cli(argv, limit=8192)
                _check_failed(res, target, "file size limit exceeded", name)
            else:
                ballast = disk / "ballast"
                st = os.statvfs(disk)
                ballast.write_bytes(b"\0" * max(0, st.f_bavail * st.f_frsize - 8192))
                try:
                    res = cli(argv)
                finally:
                    ballast.unlink()
                _check_failed(res, target, "no space left on device", name)
            # Nothing but the size line said before writing (synth, decode).
            assert [ln for ln in res.stdout.splitlines() if not ln.startswith(
                f"writing {target}: ")] == [], name  # fmt: skip


def test_read_only_file_system_is_refused_before_work(inputs) -> None:
    with tmpfs("size=1m,ro") as disk:
        if disk is None:
            pytest.skip("cannot mount a read-only tmpfs here (needs root on Linux)")
        res = cli(["decode", inputs["coded"], "-o", disk / "x.h5"])
        assert res.returncode == 2
        assert "cannot write into" in res.stderr and len(res.stderr.strip().splitlines()) == 1


def test_atomic_output_reports_out_of_space_in_one_line(tmp_path: Path) -> None:
    import errno

    target = tmp_path / "t.bin"
    target.write_bytes(b"old")
    with pytest.raises(OutputError, match=r"no space left on device while writing .*t\.bin; "
                                          r"nothing was written \(the previous file"):  # fmt: skip
        with atomic_output(target) as tmp:
            tmp.write_bytes(b"new, partial")
            raise OSError(errno.ENOSPC, "No space left on device")
    assert target.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.bin"]
    # A read error inside the block is not mistaken for a write error.
    with pytest.raises(FileNotFoundError), atomic_output(target):
        (tmp_path / "absent").read_bytes()


def test_stale_parts_of_dead_writers_are_removed(tmp_path: Path) -> None:
    target = tmp_path / "out.h5"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    with atomic_output(target) as tmp:  # learn this host's naming
        host = tmp.name.split(".")[-3].split("-")[1]
        tmp.write_bytes(b"x")
    stale = tmp_path / f".out.h5.{dead.pid}-{host}.abcd1234.part"
    live = tmp_path / f".out.h5.{os.getpid()}-{host}.efgh5678.part"
    other_host = tmp_path / f".out.h5.{dead.pid}-00000000.ijkl9012.part"
    for p in (stale, live, other_host):
        p.write_bytes(b"partial")
    assert remove_stale_parts(target) == [stale]
    assert live.exists() and other_host.exists() and not stale.exists()


def test_killed_run_leaves_no_partial_output_and_the_next_run_cleans_up(tmp_path: Path) -> None:
    target = tmp_path / "s.h5"
    target.write_bytes(b"previous output")
    env = {**os.environ, "PYTHONPATH": str(SRC), "SPARSEBTF_PROGRESS": "0"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "sparsebtf.cli.main", "synth", "--class", "stone", "--size", "32",
         "--directions", "ubo2014", "-o", str(target)],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and proc.poll() is None:
            parts = list(tmp_path.glob(".s.h5.*.part"))
            if parts and parts[0].stat().st_size > 2**20:
                break
            time.sleep(0.05)
        assert proc.poll() is None, "the writer finished before it could be killed"
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    finally:
        if proc.poll() is None:
            proc.kill()
    assert target.read_bytes() == b"previous output"
    assert len(list(tmp_path.glob(".s.h5.*.part"))) == 1  # kill -9 runs no cleanup …
    res = cli(["synth", "--class", "stone", "--size", "4", "--directions", "tiny7", "-o", target])
    assert res.returncode == 0, res.stderr
    assert list(tmp_path.glob(".s.h5.*.part")) == []  # … the next write into the folder does
    assert target.read_bytes() != b"previous output"


def test_sigterm_removes_the_temporary_file(tmp_path: Path) -> None:
    target = tmp_path / "s.h5"
    env = {**os.environ, "PYTHONPATH": str(SRC), "SPARSEBTF_PROGRESS": "0"}
    # On a busy machine the writer may rename its file between our seeing the temporary and
    # the signal's arrival: then it finished cleanly and the case was not exercised; try again.
    for _attempt in range(3):
        proc = subprocess.Popen(
            [sys.executable, "-m", "sparsebtf.cli.main", "synth", "--class", "stone", "--size",
             "32", "--directions", "ubo2014", "-o", str(target)],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and proc.poll() is None:
            if list(tmp_path.glob(".s.h5.*.part")):
                break
            time.sleep(0.05)
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=120)
        if not (proc.returncode == 0 and target.is_file()):
            break
        target.unlink()
    assert proc.returncode != 0
    assert list(tmp_path.iterdir()) == []
