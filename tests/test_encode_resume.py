"""``encode --resume``: an interrupted encode continues from its finished point ranges and
writes the file an uninterrupted run writes, byte for byte (issue 22 item 3)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sparsebtf.cli.main import main
from sparsebtf.codec import checkpoint as ckmod
from sparsebtf.codec import jobs

from .conftest import tiny_model

A = "synth:stone:16:1:tiny13"  # 16 x 16 texels: 16 points of 4 x 4
B = "synth:felt:16:3:tiny13"
OPTS = ["--batch", "2", "--tau", "16,4,4"]


@pytest.fixture(scope="module")
def model_file(tmp_path_factory) -> Path:
    from sparsebtf.storage import save_model

    path = tmp_path_factory.mktemp("model") / "tiny.h5"
    save_model(tiny_model(), path)
    return path


@pytest.fixture(autouse=True)
def _small_ranges(monkeypatch):
    """Ranges of 2 batches (4 points at --batch 2): 4 ranges for input A."""
    monkeypatch.setattr(jobs, "RANGE_BATCHES", 2)


def _encode(model: Path, inputs: list[str], out: Path, *extra: str) -> int:
    return main(["encode", *inputs, "-m", str(model), "-o", str(out), *OPTS, *extra])


def _interrupt_after(monkeypatch, n: int) -> list:
    """Ctrl-C right after the n-th range is saved; returns the list of saved ranges."""
    saved: list = []
    save = ckmod.EncodeCheckpoint.save

    def spy(self, b, lo, hi, key, part):
        save(self, b, lo, hi, key, part)
        saved.append((b, lo, hi))
        if len(saved) == n:
            raise KeyboardInterrupt

    monkeypatch.setattr(ckmod.EncodeCheckpoint, "save", spy)
    return saved


def _coded_ranges(monkeypatch) -> list:
    """Spy on the ranges actually coded (in process)."""
    seen: list = []
    code = jobs._range

    def spy(plan, x, model, stats, lo, hi, *rest, **kw):
        seen.append((lo, hi))
        return code(plan, x, model, stats, lo, hi, *rest, **kw)

    monkeypatch.setattr(jobs, "_range", spy)
    return seen


def _last_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    return err[-1] if err else ""


def test_resume_equals_uninterrupted(tmp_path, model_file, monkeypatch, capsys):
    ref = tmp_path / "ref.coded.h5"
    assert _encode(model_file, [A], ref) == 0
    assert not (tmp_path / "ref.coded.h5.checkpoint").exists()  # removed after the write
    again = tmp_path / "again.coded.h5"
    assert _encode(model_file, [A], again) == 0
    assert again.read_bytes() == ref.read_bytes()  # the file is reproducible to the byte

    out = tmp_path / "out.coded.h5"
    ck = tmp_path / "out.coded.h5.checkpoint"
    with monkeypatch.context() as m:
        _interrupt_after(m, 2)
        assert _encode(model_file, [A], out) == 130
    assert not out.exists()
    assert sorted(p.name for p in ck.iterdir()) == ["points_0_0_4.npz", "points_0_4_8.npz"]
    capsys.readouterr()

    assert _encode(model_file, [A], out) == 2  # a checkpoint needs --resume
    assert "add --resume" in _last_line(capsys)

    coded = _coded_ranges(monkeypatch)
    assert _encode(model_file, [A], out, "--resume") == 0
    assert coded == [(8, 12), (12, 16)]  # only the unfinished ranges were coded
    assert out.read_bytes() == ref.read_bytes()
    assert not ck.exists()
    assert _encode(model_file, [A], tmp_path / "x.h5", "--resume") == 2
    assert "no checkpoint" in _last_line(capsys)


@pytest.mark.parametrize(
    "change, says",
    [
        (["--tau", "16,4,5"], "plan_parameters"),
        (["--batch", "1"], "batch_size"),
        (["--std-mode", "per_channel"], "std_mode"),
        (["--log-offset", "release"], "statistics"),
    ],
)
def test_mismatch_refused_in_one_line(tmp_path, model_file, monkeypatch, capsys, change, says):
    out = tmp_path / "out.h5"
    with monkeypatch.context() as m:
        _interrupt_after(m, 1)
        assert _encode(model_file, [A], out) == 130
    capsys.readouterr()
    assert main(["encode", A, "-m", str(model_file), "-o", str(out), *OPTS, *change,
                 "--resume"]) == 2  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "was made with other inputs or encoding parameters" in err[0]
    assert says in err[0] and "points_0_0_4.npz" in err[0], err
    assert not out.exists()


def test_other_input_and_damaged_file_refused(tmp_path, model_file, monkeypatch, capsys):
    out = tmp_path / "out.h5"
    with monkeypatch.context() as m:
        _interrupt_after(m, 2)
        assert _encode(model_file, [A], out) == 130
    capsys.readouterr()
    assert _encode(model_file, ["synth:stone:16:2:tiny13"], out, "--resume") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "input" in err[0] and "stone-16x16-s2" in err[0], err
    assert _encode(model_file, ["synth:felt:8:3:tiny13"], out, "--resume") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "input" in err[0] and "shape" in err[0], err

    damaged = out.with_name(out.name + ".checkpoint") / "points_0_4_8.npz"
    good = damaged.read_bytes()
    with np.load(damaged) as f:  # the largest array's bytes: coefficient values
        payload = max((f[k] for k in f.files), key=lambda a: a.nbytes).tobytes()
    at = good.index(payload) + len(payload) // 2
    for data in (good[: len(good) // 2], good[:at] + bytes([good[at] ^ 0x40]) + good[at + 1 :]):
        damaged.write_bytes(data)  # truncated; one flipped bit in the values
        assert _encode(model_file, [A], out, "--resume") == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "points_0_4_8.npz" in err[0] and "damaged" in err[0], err
    assert not out.exists()


def test_multi_btf_resume(tmp_path, model_file, monkeypatch):
    ref, out = tmp_path / "ref", tmp_path / "out"
    assert _encode(model_file, [A, B], f"{ref}/") == 0
    with monkeypatch.context() as m:
        saved = _interrupt_after(m, 5)  # A's 4 ranges, then B's first
        assert _encode(model_file, [A, B], f"{out}/") == 130
    assert saved[-1] == (1, 0, 4)
    assert [p.name for p in out.iterdir()] == ["synth_stone_16_1_tiny13.coded.h5"]
    coded = _coded_ranges(monkeypatch)
    assert _encode(model_file, [A, B], f"{out}/", "--resume") == 0
    assert coded == [(4, 8), (8, 12), (12, 16)]  # B's unfinished ranges
    names = sorted(p.name for p in ref.iterdir())
    assert names == sorted(p.name for p in out.iterdir()) and len(names) == 2
    for n in names:
        assert (out / n).read_bytes() == (ref / n).read_bytes(), n
    assert not (tmp_path / "out.checkpoint").exists()


def test_same_name_other_content_refused(tmp_path):
    """Two BTFs of one name and shape: their statistics (the content fingerprint) differ."""
    from sparsebtf.codec import encode_many
    from sparsebtf.errors import BTFInputError

    from .conftest import smooth_btf

    model = tiny_model()
    ck = tmp_path / "ck"
    first, second = (smooth_btf(s, size=16, name="same") for s in (0, 1))
    kw = dict(tau=(16, 4, 4), batch_size=2, progress=False, checkpoint_dir=ck)
    ref = next(encode_many([first], model, **kw))  # the library leaves the folder
    assert len(list(ck.iterdir())) == 4
    with pytest.raises(BTFInputError, match="statistics") as e:
        next(encode_many([second], model, **kw))
    assert "\n" not in str(e.value) and "input" not in str(e.value).split("(")[1]
    again = next(encode_many([first], model, **kw))  # every range read back
    assert again.codes["Y"].values.tobytes() == ref.codes["Y"].values.tobytes()


def _saved_ranges(monkeypatch) -> list:
    """Spy on the ranges saved (on the client: also for a Dask encode)."""
    saved: list = []
    save = ckmod.EncodeCheckpoint.save

    def spy(self, b, lo, hi, key, part):
        save(self, b, lo, hi, key, part)
        saved.append((b, lo, hi))

    monkeypatch.setattr(ckmod.EncodeCheckpoint, "save", spy)
    return saved


def test_dask_encode_resumes(tmp_path, model_file, monkeypatch):
    """Interrupted on a local cluster of 2 workers (started here), resumed on another: the
    ranges are the same wherever they run, and so is the file."""
    ref, out = tmp_path / "ref", tmp_path / "out"
    assert _encode(model_file, [A, B], f"{ref}/") == 0  # in process
    with monkeypatch.context() as m:
        _interrupt_after(m, 3)
        assert _encode(model_file, [A, B], f"{out}/", "--workers", "2") == 130
    saved = _saved_ranges(monkeypatch)
    assert _encode(model_file, [A, B], f"{out}/", "--workers", "2", "--resume") == 0
    assert saved == [(0, 12, 16), (1, 0, 4), (1, 4, 8), (1, 8, 12), (1, 12, 16)]
    for n in sorted(p.name for p in ref.iterdir()):
        assert (out / n).read_bytes() == (ref / n).read_bytes(), n
    assert not (tmp_path / "out.checkpoint").exists()


SLOW_ENCODE = """
import sys, time
from sparsebtf.codec import checkpoint, jobs
from sparsebtf.cli.main import main
jobs.RANGE_BATCHES = 2
save = checkpoint.EncodeCheckpoint.save
def slow(*a):
    save(*a)
    time.sleep(0.5)  # time for the test to kill it between two ranges
checkpoint.EncodeCheckpoint.save = slow
sys.exit(main(sys.argv[1:]))
"""


def test_resume_after_kill(tmp_path, model_file):
    """``kill -9`` after the first range is saved; --resume writes the uninterrupted file."""
    import os
    import signal
    import subprocess
    import sys

    from ._cluster import wait_for

    ref, out = tmp_path / "ref.h5", tmp_path / "out.h5"
    assert _encode(model_file, [A], ref) == 0
    env = {**os.environ, "PYTHONPATH": str(Path(ckmod.__file__).parents[2])}
    argv = ["encode", A, "-m", str(model_file), "-o", str(out), *OPTS]
    p = subprocess.Popen([sys.executable, "-c", SLOW_ENCODE, *argv], env=env,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    try:
        wait_for(tmp_path / "out.h5.checkpoint" / "points_0_0_4.npz")
        p.send_signal(signal.SIGKILL)
    finally:
        p.wait(timeout=60)
    assert p.returncode == -signal.SIGKILL and not out.exists()
    assert _encode(model_file, [A], out, "--resume") == 0
    assert out.read_bytes() == ref.read_bytes()
    assert not (tmp_path / "out.h5.checkpoint").exists()


@pytest.mark.parametrize(("budget", "ratio"), [("paper", "40"), ("stored", "8")])
def test_rate_control_resumes(tmp_path, model_file, monkeypatch, budget, ratio):
    """A --target-ratio encode keeps per-range candidates (not codes): they resume too."""
    rate = ["--batch", "2", "--target-ratio", ratio, "--budget", budget]
    ref, out = tmp_path / "ref.h5", tmp_path / "out.h5"
    assert main(["encode", A, "-m", str(model_file), "-o", str(ref), *rate]) == 0
    with monkeypatch.context() as m:
        _interrupt_after(m, 3)
        assert main(["encode", A, "-m", str(model_file), "-o", str(out), *rate]) == 130
    assert main(["encode", A, "-m", str(model_file), "-o", str(out), *rate, "--resume"]) == 0
    assert out.read_bytes() == ref.read_bytes()
