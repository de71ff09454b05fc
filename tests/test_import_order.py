"""Import order: the scene script of docs/rendering.md ("Import order") in both orders.

Dr.Jit loads its libLLVM while ``import drjit`` runs. The start-up hook
(``sparsebtf-drjit-llvm.pth``, built by ``setup.py`` from ``sparsebtf/_llvm_startup.py``) sets
``DRJIT_LIBLLVM_PATH`` first, so both orders render; without it, ``import mitsuba`` first
loads the system's library, and where that is older than 17 ``import sparsebtf.mitsuba`` stops
with one line instead of a kernel aborting the process.

Each case runs the script extracted from the doc in a subprocess (a bad libLLVM aborts the
process that loads it). The hook is emulated as Python runs an installed one: ``site``
processing the built ``.pth`` line from a folder (``site.addsitedir``), before the script. An
installed hook is turned off in the children (``SPARSEBTF_LLVM_HOOK=0``) so each case sees only
what it says. Skips, with the reason, without Mitsuba or a usable libLLVM.
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import sparsebtf
from sparsebtf import _llvm_startup as hook
from sparsebtf import llvm

from .conftest import smooth_btf, tiny_model

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "rendering.md"
SETUP = ROOT / "setup.py"
IMPORT_MI = "import mitsuba as mi"
IMPORT_SB = "import sparsebtf.mitsuba"
ONE_LINE = re.compile(
    r"^sparsebtf\.llvm\.LLVMImportOrderError: Dr\.Jit was imported before sparsebtf\.mitsuba "
    r"and loaded LLVM (1[56])\.\d+\.\d+ \((\S+)\), .* set DRJIT_LIBLLVM_PATH=(\S+) before"
)
# How the children start: the hook (if given) as site runs a .pth, then the script as __main__,
# then the libLLVM files the process mapped.
HARNESS = """
import os, runpy, site, sys
hook_dir = sys.argv.pop(1)
if hook_dir:
    os.environ.pop("SPARSEBTF_LLVM_HOOK", None)
    site.addsitedir(hook_dir)
sys.argv = sys.argv[1:]
runpy.run_path(sys.argv[0], run_name="__main__")
maps = sorted({l.split()[-1] for l in open("/proc/self/maps") if "/libLLVM" in l})
print("MAPPED", *maps)
"""


def _pth_line() -> str:
    if not SETUP.exists():
        pytest.skip(f"{SETUP} missing: the hook's .pth line is built there (run from a checkout)")
    spec = importlib.util.spec_from_file_location("sparsebtf_setup", SETUP)
    setup = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(setup)  # setup() itself runs only as __main__
    return setup.pth_line(Path(hook.__file__).read_text(encoding="utf-8"))


def doc_script() -> str:
    """The python block after the doc's ``scene-script`` marker."""
    text = DOC.read_text(encoding="utf-8")
    m = re.search(r"<!-- scene-script[^>]*-->\s*```python\n(.*?)```", text, re.S)
    assert m, f"{DOC}: no python block after the scene-script marker"
    return m.group(1)


def in_order(script: str, first: str) -> str:
    """``script`` with its two imports in the given order (``mitsuba`` or ``sparsebtf``)."""
    lines = script.splitlines()
    i = next(k for k, x in enumerate(lines) if x == IMPORT_MI)
    j = next(k for k, x in enumerate(lines) if x.startswith(IMPORT_SB))
    assert j == i + 1, "the doc's script keeps its two imports on adjacent lines"
    if first == "sparsebtf":
        lines[i], lines[j] = lines[j], lines[i]
    return "\n".join(lines) + "\n"


def test_the_hook_sets_the_path_only_when_unset(tmp_path, monkeypatch):
    """The built .pth line, run as site runs it: the newest libLLVM >= 17 beside site-packages,
    marked as the hook's; never over the user's variable (even empty); never LLVM 15/16."""
    lib = tmp_path / "prefix" / "lib"
    site_dir = lib / "python3.11" / "site-packages"
    site_dir.mkdir(parents=True)
    for name in ("libLLVM-15.so.1", "libLLVM.so.16.0", "libLLVM.so.19.1", "libLLVM.so.23.1"):
        (lib / name).write_bytes(b"")
    line = _pth_line()
    assert line.startswith("import ") and line.count("\n") == 1
    for var in (hook.ENV, hook.MARK, hook.OFF):
        monkeypatch.delenv(var, raising=False)
    exec(line, {}, {"sitedir": str(site_dir)})
    assert os.environ[hook.ENV] == os.environ[hook.MARK] == str(lib / "libLLVM.so.23.1")
    monkeypatch.setenv(hook.ENV, "")
    monkeypatch.delenv(hook.MARK)
    exec(line, {}, {"sitedir": str(site_dir)})
    assert os.environ[hook.ENV] == "" and hook.MARK not in os.environ
    monkeypatch.delenv(hook.ENV)
    monkeypatch.setenv(hook.OFF, "0")
    exec(line, {}, {"sitedir": str(site_dir)})
    assert hook.ENV not in os.environ
    for name in ("libLLVM.so.19.1", "libLLVM.so.23.1"):
        (lib / name).unlink()
    assert hook.find([str(lib)]) is None  # only 15 and 16 left: not those
    assert [hook._major(n) for n in ("libLLVM-17.so", "libLLVM.so.18.1", "libLLVM.so", "x")] == [
        17, 18, -1, -1
    ]  # fmt: skip
    # A real interpreter processing the .pth from a folder, as at start-up.
    (site_dir / "sparsebtf-drjit-llvm.pth").write_text(line, encoding="utf-8")
    (lib / "libLLVM.so.21.1").write_bytes(b"")
    code = (f"import os, site; os.environ.pop({hook.OFF!r}); site.addsitedir({str(site_dir)!r}); "
            f"print(os.environ.get({hook.ENV!r}))")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], env=_child_env(), capture_output=True,
                         text=True, timeout=60, check=True).stdout.strip()  # fmt: skip
    assert out == str(lib / "libLLVM.so.21.1")


# --------------------------------------------------------------------------- the doc's script

needs_mitsuba = pytest.mark.skipif(
    importlib.util.find_spec("mitsuba") is None or importlib.util.find_spec("drjit") is None,
    reason="mitsuba/drjit not installed (pip install mitsuba drjit)",
)


@pytest.fixture(scope="module")
def usable() -> llvm.LLVMStatus:
    st = llvm.configure()  # the search (or, with drjit imported here, the library it loaded)
    if not st.ok:
        pytest.skip(f"no libLLVM usable by Dr.Jit here: {st.message()}")
    return st


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory) -> Path:
    """The doc's script in both orders, a tiny coded material (model file beside it) and the
    built hook in a folder of its own."""
    from sparsebtf.codec import encode
    from sparsebtf.storage import save_coded, save_model

    d = tmp_path_factory.mktemp("scene")
    model = tiny_model()
    save_model(model, d / "model.h5")
    save_coded(encode(smooth_btf(9), model, tau=(100, 20, 20), eps=0.0, progress=False),
               d / "m.coded.h5")  # fmt: skip
    script = doc_script()
    for first in ("mitsuba", "sparsebtf"):
        (d / f"{first}_first.py").write_text(in_order(script, first), encoding="utf-8")
    (d / "hook").mkdir()
    (d / "hook" / "sparsebtf-drjit-llvm.pth").write_text(_pth_line(), encoding="utf-8")
    return d


def _child_env(**extra: str) -> dict[str, str]:
    """This environment without a libLLVM choice, an installed hook off, this sparsebtf."""
    env = {k: v for k, v in os.environ.items() if k not in (hook.ENV, hook.MARK)}
    env.update(SPARSEBTF_LLVM_HOOK="0", **extra)
    src = str(Path(sparsebtf.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (src, env.get("PYTHONPATH")) if p)
    return env


def _run(d: Path, first: str, hook_on: bool, **env_extra: str) -> subprocess.CompletedProcess:
    (d / "my_scene.png").unlink(missing_ok=True)
    env = _child_env(**env_extra)
    args = [str(d / "hook") if hook_on else "", f"{first}_first.py", "m.coded.h5", "16", "4"]
    return subprocess.run([sys.executable, "-c", HARNESS, *args], cwd=d, env=env,
                          capture_output=True, text=True, timeout=300)  # fmt: skip


def _rendered(d: Path, r: subprocess.CompletedProcess) -> str:
    """Check the run rendered; the libLLVM it names (the variant message = the mapped file)."""
    assert r.returncode == 0, r.stderr[-3000:]
    assert "LLVM ERROR" not in r.stderr
    from skimage.io import imread

    img = imread(d / "my_scene.png")
    assert img.shape[:2] == (16, 16) and np.asarray(img, float).mean() > 1, "a lit scene"
    m = re.search(r"^Dr\.Jit LLVM backend: (\S+) \(LLVM (\d+)\.", r.stdout, re.M)
    mapped = re.search(r"^MAPPED (.*)$", r.stdout, re.M).group(1).split()
    if m is None:  # the scalar fallback (no libLLVM >= 17 at all)
        assert "scalar_rgb" in r.stdout + r.stderr
        return ""
    assert int(m.group(2)) >= llvm.MIN_MAJOR
    assert m.group(1) in mapped, (m.group(1), mapped)  # the library Dr.Jit actually loaded
    return m.group(1)


@needs_mitsuba
@pytest.mark.parametrize("first", ["mitsuba", "sparsebtf"])
def test_with_the_hook_either_order_renders(scene_dir, usable, first):
    found = hook.find(hook.lib_dirs())
    if found is None:
        pytest.skip("no pip-installed libLLVM >= 17 for the hook (pip install 'sparsebtf[render]')")
    r = _run(scene_dir, first, hook_on=True)
    assert _rendered(scene_dir, r) == os.path.realpath(found)


def _default_llvm() -> int:
    """The major version Dr.Jit loads here when nothing points it anywhere (-1: none)."""
    env = _child_env()
    code = "import drjit as dr; print(dr.detail.llvm_version()[0])"  # no kernel: no abort
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                       timeout=120)  # fmt: skip
    return int(r.stdout.split()[-1]) if r.returncode == 0 and r.stdout.split() else -1


@needs_mitsuba
def test_without_the_hook_sparsebtf_first_renders(scene_dir, usable):
    _rendered(scene_dir, _run(scene_dir, "sparsebtf", hook_on=False))


@needs_mitsuba
def test_without_the_hook_mitsuba_first_renders_or_stops_with_one_line(scene_dir, usable):
    """Where Dr.Jit's own choice is LLVM 15/16 (Debian 12), the import stops with the one line
    before any kernel; the fix it names, run, renders. Where it is >= 17 (libllvm19, as on CI),
    the script renders."""
    major = _default_llvm()
    r = _run(scene_dir, "mitsuba", hook_on=False)
    if major not in (15, 16):
        _rendered(scene_dir, r)
        return
    assert r.returncode == 1 and "LLVM ERROR" not in r.stderr, r.stderr[-3000:]
    last = r.stderr.strip().splitlines()[-1]
    m = ONE_LINE.match(last)
    assert m and int(m.group(1)) == major, last
    assert not (scene_dir / "my_scene.png").exists()
    fixed = _run(scene_dir, "mitsuba", hook_on=False, DRJIT_LIBLLVM_PATH=m.group(3))
    assert _rendered(scene_dir, fixed) == m.group(3)
    # The user's own DRJIT_LIBLLVM_PATH naming the old library: the line says to change it.
    own = _run(scene_dir, "mitsuba", hook_on=False, DRJIT_LIBLLVM_PATH=m.group(2))
    assert own.returncode == 1, own.stderr[-3000:]
    assert own.stderr.strip().splitlines()[-1].endswith(
        f"DRJIT_LIBLLVM_PATH is set to {m.group(2)}: set it to {m.group(3)} instead, before "
        "Python starts")  # fmt: skip


@needs_mitsuba
def test_a_variant_set_without_llvm_is_kept_whatever_dr_jit_loaded(usable):
    """``scalar_rgb`` set before the import does not use the LLVM backend: no stop, even where
    Dr.Jit loaded LLVM 15 (the check is for llvm variants only)."""
    code = ("import mitsuba as mi\nmi.set_variant('scalar_rgb')\nimport sparsebtf.mitsuba as sbm\n"
            "print(sbm.variant, '|', sbm.variant_message)\n")  # fmt: skip
    r = subprocess.run([sys.executable, "-c", code], env=_child_env(), capture_output=True,
                       text=True, timeout=120)  # fmt: skip
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip() == "scalar_rgb | keeping the active Mitsuba variant scalar_rgb"
