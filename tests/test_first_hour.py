"""What a new user meets first: the README's commands and snippets run as written, every option
has a help text, and the wheel carries the bundled model, the shaders and the viewer."""

import argparse
import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

import sparsebtf
from sparsebtf.cli.main import build_parser
from sparsebtf.storage.bundled import load_bundled

from .conftest import readme_python_api_blocks

ROOT = Path(__file__).resolve().parents[1]
SRC = Path(sparsebtf.__file__).resolve().parents[1]
README = ROOT / "README.md"


def readme_block(heading: str, lang: str = "bash") -> str:
    """The first ```lang block after the README heading ``## heading``."""
    text = README.read_text()
    start = text.index(f"\n## {heading}\n")
    m = re.compile(rf"```{lang}\n(.*?)```", re.S).search(text, start)
    assert m is not None, f"no {lang} block under '## {heading}'"
    return m.group(1)


def shell(block: str, cwd: Path, **env: str) -> subprocess.CompletedProcess:
    """Run a README block with bash -eu, ``sparsebtf`` meaning this checkout's command."""
    bindir = cwd / "bin"
    bindir.mkdir(exist_ok=True)
    shim = bindir / "sparsebtf"
    shim.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m sparsebtf.cli.main "$@"\n')
    shim.chmod(0o755)
    full = {**os.environ, "PATH": f"{bindir}{os.pathsep}{os.environ['PATH']}",
            "PYTHONPATH": str(SRC), "SPARSEBTF_PROGRESS": "0", **env}  # fmt: skip
    r = subprocess.run(["bash", "-euo", "pipefail", "-c", "set -x\n" + block], cwd=cwd,
                       env=full, capture_output=True, text=True, timeout=900)  # fmt: skip
    assert r.returncode == 0, f"README block failed:\n{r.stderr[-4000:]}\n{r.stdout[-2000:]}"
    return r


@pytest.mark.slow
def test_readme_command_line_runs_top_to_bottom(tmp_path):
    block = readme_block("Command line")
    r = shell(block, tmp_path, SIZE="10")
    lines = [ln for ln in block.splitlines() if ln.startswith("sparsebtf ")]
    assert len(lines) >= 15 and r.stderr.count("+ sparsebtf ") >= len(lines)
    for f in ("stone.png", "stone.coded.h5", "out", "model.h5", "stone.mine.h5",
              "stone.r50.h5", "mix.h5", "strip/blend_strip.png", "corner.h5", "cmp.png",
              "viewer/index.html"):  # fmt: skip
        assert (tmp_path / f).exists(), f
    assert "(asked 50)" in r.stdout
    # the ratio asked for is raw / the file's size, as `ls -l` shows it (README "Ratios")
    raw = 10 * 10 * 151 * 151 * 3 * 2  # SIZE=10
    size = (tmp_path / "stone.r50.h5").stat().st_size
    assert size <= raw / 50 and raw / size == pytest.approx(50, rel=0.01)
    # outputs are readable by the group, like any other tool's (umask 022 here)
    assert (tmp_path / "stone.coded.h5").stat().st_mode & 0o044 == 0o044


@pytest.mark.slow
def test_readme_measured_btf_section_on_a_stand_in(tmp_path):
    from sparsebtf.data.directions import ubo2014
    from sparsebtf.formats.ubo2014_write import write_ubo2014
    from sparsebtf.llvm import configure

    if not configure().ok:
        pytest.skip("the section renders with Mitsuba's LLVM backend: apt-get install libllvm19")
    rng = np.random.default_rng(3)
    d = ubo2014()
    h = w = 10
    spatial = [rng.uniform(0.5, 1.0, (h * w, 2)).astype(np.float32) for _ in range(3)]
    angular = [(-1 + 0.2 * rng.random((len(d) ** 2, 2))).astype(np.float32) for _ in range(3)]
    btf = tmp_path / "standin_resampled_W10xH10_L151xV151.btf"
    write_ubo2014(btf, spatial, angular, h, w, d, d, "DFMF", "float")
    r = shell(readme_block("Compress a measured BTF"), tmp_path, BTF=str(btf))
    assert "bundled model 'release'" in r.stdout and "PSNR" in r.stdout
    assert (tmp_path / "carpet07.png").exists()
    assert (tmp_path / "carpet07-viewer" / "data.bin").exists()


@pytest.mark.slow
def test_readme_python_snippets_run_in_sequence(readme_python_run):
    """Both blocks of the README's Python API, in one interpreter (the session's one run:
    conftest.readme_python_run)."""
    assert len(readme_python_api_blocks()) == 2
    cwd, r = readme_python_run
    assert r.returncode == 0, r.stderr[-4000:]
    assert (cwd / "stone.coded.h5").exists()


def _actions(parser: argparse.ArgumentParser, name: str):
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for sub_name, sub in a.choices.items():
                yield from _actions(sub, f"{name} {sub_name}".strip())
        elif not isinstance(a, argparse._HelpAction):
            yield name, a


def test_every_option_of_every_command_has_help():
    missing = [f"{name} {a.option_strings or a.dest}"
               for name, a in _actions(build_parser(), "") if not a.help]  # fmt: skip
    assert missing == []
    # and no reStructuredText markup leaks into a description
    for name, a in _actions(build_parser(), ""):
        assert "``" not in (a.help or ""), name


@pytest.mark.slow
def test_wheel_carries_model_shaders_and_viewer(tmp_path):
    """Build the wheel (offline: no build isolation, setuptools >= 77 from the dev extra) from
    a copy of the sources and check what it holds; then install it into a fresh folder."""
    import setuptools

    if int(setuptools.__version__.split(".")[0]) < 77:
        pytest.skip(f"setuptools {setuptools.__version__} < 77: pip install -e '.[dev]'")
    src = tmp_path / "src-copy"
    src.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        (src / name).write_bytes((ROOT / name).read_bytes())
    import shutil

    shutil.copytree(SRC / "sparsebtf", src / "src" / "sparsebtf",
                    ignore=shutil.ignore_patterns("__pycache__"))  # fmt: skip
    r = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
         "-w", str(tmp_path / "dist"), str(src)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    (wheel,) = (tmp_path / "dist").glob("sparsebtf-*.whl")
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        model = z.read("sparsebtf/models/release.h5")
    bundled = SRC / "sparsebtf" / "models"
    assert model == (bundled / "release.h5").read_bytes()
    for need in ("sparsebtf/models/LICENSE-SparseBTF", "sparsebtf/models/PROVENANCE.md",
                 "sparsebtf/rendering/shaders/sparsebtf_lookup.glsl",
                 "sparsebtf/rendering/shaders/viewer_scene.glsl",
                 "sparsebtf/rendering/viewer/static/index.html",
                 "sparsebtf/rendering/viewer/static/viewer.js", "sparsebtf/py.typed"):  # fmt: skip
        assert need in names, need
    assert any(n.endswith("licenses/LICENSE") for n in names)
    # installed (not editable) into a fresh folder, the package finds the model in itself
    site = tmp_path / "site"
    pip = [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(site)]
    subprocess.run([*pip, str(wheel)], check=True, timeout=300, capture_output=True)
    r = subprocess.run(
        [sys.executable, "-c", "import sparsebtf.storage.bundled as b; print(b.models_dir()); "
         "print(b.load_bundled().content_hash)"],
        cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(site)}, capture_output=True,
        text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    folder, digest = r.stdout.split()
    assert folder.startswith(str(site)) and digest == load_bundled().content_hash


@pytest.mark.slow
def test_demo_prints_the_trained_and_the_bundled_rows(tmp_path, capsys):
    from sparsebtf.cli.demo import DemoConfig, run_demo

    cfg = DemoConfig(train_materials=(("carpet", 1), ("stone", 1)), test_materials=(("felt", 7),),
                     train_size=10, test_size=10, n_dictionaries=2, iters=1, sample=1.0,
                     taus=((256, 32, 32),), ssim_images=2)  # fmt: skip
    result = run_demo(tmp_path, config=cfg)
    out = capsys.readouterr().out
    assert [(r["model"], r["tau"]) for r in result["rows"]] == [
        ("trained", "256/32/32"), ("release", "885/64/64")]  # fmt: skip
    assert "file bytes" in out and "T4+dict" in out and " release " in out
    release = result["rows"][1]
    assert release["compression_ratio_per_material"] > release["compression_ratio"]
    assert (tmp_path / "synth-felt-10x10-s7_release_tau885.h5").exists()
