"""Shared fixtures: small BTFs (4x4 patches, 13 directions) and the authors' release files."""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sparsebtf.data.btf import ArrayBTF
from sparsebtf.data.directions import tiny


def shared_dir() -> Path | None:
    """``../shared`` of the checkout, or $SPARSEBTF_SHARED (set by .ci/run)."""
    env = os.environ.get("SPARSEBTF_SHARED")
    cand = Path(env) if env else Path(__file__).resolve().parents[2] / "shared"
    return cand if (cand / "official").is_dir() else None


@pytest.fixture
def official() -> Path:
    d = shared_dir()
    if d is None:
        pytest.skip("the authors' release (shared/official) is not available; set SPARSEBTF_SHARED")
    return d / "official"


def _libc_malloc_trim():
    name = ctypes.util.find_library("c")
    try:
        return ctypes.CDLL(name).malloc_trim if name else None
    except (OSError, AttributeError):  # not glibc
        return None


_malloc_trim = _libc_malloc_trim()


def release_memory() -> None:
    """Drop what the library keeps per process (opened BTFs, Mitsuba's loaded materials, captured
    samples' scenes) and hand freed heap pages back to the OS: one pytest process runs every test
    file, so what one file leaves behind would otherwise add up with the next file's peak."""
    jobs = sys.modules.get("sparsebtf.codec.jobs")
    if jobs is not None:
        jobs._open_path.cache_clear()
    materials = sys.modules.get("sparsebtf.rendering.mitsuba.materials")
    if materials is not None:
        with materials._lock:
            materials._cache.clear()
    writer = sys.modules.get("sparsebtf.data.capture.writer")
    if writer is not None:
        writer._loaded.clear()
    gc.collect()
    if _malloc_trim is not None:
        _malloc_trim(0)


@pytest.fixture(autouse=True, scope="module")
def _release_memory_after_module():
    yield
    release_memory()


@pytest.fixture(autouse=True)
def _cache_dir(tmp_path_factory, monkeypatch):
    """Synthetic-material cache in a per-session temporary folder; no bars, no cluster."""
    monkeypatch.setenv("SPARSEBTF_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))
    monkeypatch.setenv("SPARSEBTF_PROGRESS", "0")
    monkeypatch.delenv("SPARSEBTF_SCHEDULER", raising=False)  # tests run in process


def smooth_btf(seed: int, size: int = 8, n_dirs: int = 13, name: str | None = None) -> ArrayBTF:
    """A small positive BTF with spatial texture and smooth angular behaviour."""
    rng = np.random.default_rng(seed)
    d = tiny(n_dirs)
    base = rng.uniform(0.05, 0.8, (size, size, 1, 1, 3))
    cl, cv = d.xyz[:, 2], d.xyz[:, 2]
    ang = (0.3 + cl)[:, None] * (0.5 + cv)[None, :]
    noise = 1 + 0.1 * rng.standard_normal((size, size, n_dirs, n_dirs, 3))
    data = base * ang[None, None, :, :, None] * np.clip(noise, 0.5, None)
    return ArrayBTF(data.astype(np.float32), d, d, name=name or f"smooth{seed}")


@pytest.fixture
def small_btfs() -> list[ArrayBTF]:
    return [smooth_btf(s) for s in range(3)]


def tiny_model(max_iter: int = 2):
    """The tests' small model: K = 3 per channel, trained on ``smooth_btf(0..2)`` (4x4
    patches, 13 directions, tau_l = 16/4/4, every point)."""
    from sparsebtf.codec import train

    btfs = [smooth_btf(s) for s in range(3)]
    return train(
        btfs, n_dictionaries=3, tau_train=(16, 4, 4), patch=4, sample=1.0, max_iter=max_iter,
        progress=False,
    )  # fmt: skip



def tight_bound(coded):
    """``coded`` with a bound on ln(RGB + eps) that clamps about half its values (each angular
    image's shared μ), so that tests see every decoder's clamp at work."""
    from dataclasses import replace

    from sparsebtf.points.preprocessing import round_up_bound

    bound = round_up_bound(coded.stats.mean.mean(axis=2))
    return replace(coded, stats=replace(coded.stats, bound=bound))


README = Path(__file__).resolve().parents[1] / "README.md"


def readme_python_api_blocks() -> list[str]:
    """The python blocks under the README's ``## Python API``, as written there."""
    text = README.read_text()
    start = text.index("\n## Python API\n")
    end = text.index("\n## ", start + 1)
    return re.findall(r"```python\n(.*?)```", text[start:end], re.S)


@pytest.fixture(scope="session")
def readme_python_run(tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess]:
    """The README's Python API blocks run in sequence, as written, in one fresh interpreter
    (the first block trains and encodes 20x20-texel materials at 151 x 151 directions: run once
    for the tests that check the blocks run and what the first one prints and writes)."""
    import sparsebtf

    src = Path(sparsebtf.__file__).resolve().parents[1]
    cwd = tmp_path_factory.mktemp("readme_python")
    env = {**os.environ, "PYTHONPATH": str(src), "SPARSEBTF_PROGRESS": "0",
           "SPARSEBTF_CACHE": str(tmp_path_factory.getbasetemp() / "cache")}  # fmt: skip
    r = subprocess.run([sys.executable, "-c", "\n".join(readme_python_api_blocks())], cwd=cwd,
                       capture_output=True, text=True, env=env, timeout=900)  # fmt: skip
    return cwd, r


# ------------------------------------------------- coded stores of the highlight tests
# (module scope, each on the requesting module's own ``model``)


@pytest.fixture(scope="module")
def levels(model):
    """``glossy_btf`` coded at the highlight tests' levels with the store."""
    from .highlight_materials import glossy_levels

    return glossy_levels(model)


@pytest.fixture(scope="module")
def tinted_level(model):
    """A level of ``tinted_btf`` whose store is tinted."""
    from .highlight_materials import first_tinted_level

    return first_tinted_level(model)


@pytest.fixture(scope="module")
def lobed(model):
    """A coded material whose store has lobes and entries."""
    from .highlight_materials import lobed_material

    return lobed_material(model)
