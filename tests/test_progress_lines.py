"""Progress on a log: lines with rate and ETA when stderr is not a terminal (issue 22 item 4)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"

# 25 updates of 0.1 s: ~2.5 s of "work", so lines at 5 % steps at most once a second.
SCRIPT = """
import time
from sparsebtf._progress import bar, progress
with bar(25, "encode stone", "pt") as pb:
    for _ in range(25):
        time.sleep(0.1)
        pb.update(1)
for _ in progress(range(3), desc="quick"):
    pass
"""


def _run(env_progress: str | None) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "SPARSEBTF_PROGRESS"}
    env["PYTHONPATH"] = str(SRC)
    if env_progress is not None:
        env["SPARSEBTF_PROGRESS"] = env_progress
    return subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True,
                          text=True, timeout=120)  # fmt: skip


def test_lines_on_a_pipe():
    r = _run(None)
    assert r.returncode == 0, r.stderr
    lines = r.stderr.splitlines()
    assert "\r" not in r.stderr  # no bar redrawn in place
    steps = [ln for ln in lines if ln.startswith("sparsebtf: encode stone: ") and "ETA" in ln]
    assert 1 <= len(steps) <= 5, lines  # ~2.5 s: at most one line a second
    assert all("pt/s" in ln and "/25 pt)" in ln for ln in steps), steps
    assert lines[-1].startswith("sparsebtf: encode stone: done, 25 pt in "), lines
    assert not any("quick" in ln for ln in lines)  # quick work stays quiet


def test_silenced_and_forced():
    assert _run("0").stderr == ""
    forced = _run("1").stderr
    assert "sparsebtf: encode stone" not in forced and "25/25" in forced  # tqdm's bar
