"""Find a libLLVM that Dr.Jit's LLVM backend can use, and pick the Mitsuba variant.

Dr.Jit 1.5 JIT-compiles its CPU kernels with the system's ``libLLVM``. Which one matters
(docs/rendering.md):

* LLVM 14 is refused cleanly by Dr.Jit ("requires LLVM 15 or newer"),
* LLVM 15 and 16 (what Mesa pulls in) **abort the whole process** on the first kernel that uses
  ``dr.minimum`` — a SIGABRT, not a Python exception — so this module needs 17 or newer,
* LLVM 17+ works: Debian's ``libllvm19`` (root), or without root the PyPI wheel
  ``karellen-llvm-core`` (LLVM 23, with the libc++ it links against; the ``render`` extra
  installs it on Linux x86-64), found under the Python environment's ``lib/``.

So a library is never tried in this process: :func:`probe_libllvm` runs a tiny Dr.Jit kernel in
a **subprocess** with ``DRJIT_LIBLLVM_PATH`` pointing at the candidate, and only a candidate that
passes is exported to this process's environment (:func:`configure`) — before ``drjit`` is
imported, because Dr.Jit reads the variable once. ``DRJIT_LIBLLVM_PATH`` set by the user
overrides the search (it is still probed). Results are cached per process.

:func:`choose_variant` returns ``"cuda_ad_rgb"`` (only when asked for and a GPU works),
``"llvm_ad_rgb"`` when a usable libLLVM was found, and otherwise ``"scalar_rgb"`` with a message
saying why (the scalar variant runs the BSDF in Python per ray: tiny renders only);
:func:`activate_variant` sets it. This module sits below every user of Mitsuba (the render
plugins, ``capture``), so that none of them imports another for it.
"""

from __future__ import annotations

import glob
import os
import re
import subprocess
import sys
from dataclasses import dataclass, field

__all__ = [
    "LLVMStatus",
    "candidate_libraries",
    "choose_variant",
    "configure",
    "probe_libllvm",
]

#: Directories searched for libLLVM (Debian multiarch first).
SEARCH_DIRS = (
    "/usr/lib/x86_64-linux-gnu",
    "/usr/lib/aarch64-linux-gnu",
    "/usr/lib64",
    "/usr/lib",
    "/usr/local/lib",
    "/opt/homebrew/opt/llvm/lib",
    "/usr/local/opt/llvm/lib",
)
#: Major versions tried, best first (then any newer one). 15 and 16 are excluded on purpose:
#: they abort the process.
GOOD_MAJORS = (19, 18, 17, 20, 21, 22, 23)
#: The oldest LLVM this module uses (Dr.Jit's own floor is 15, but 15 and 16 abort).
MIN_MAJOR = 17
#: Wheels on PyPI that ship a libLLVM with its dependencies (installed under ``<prefix>/lib``).
PYPI_WHEELS = ("karellen-llvm-core",)


def search_dirs() -> list[str]:
    """Where libLLVM is looked for: the Python environment's ``lib/`` (a pip-installed wheel,
    :data:`PYPI_WHEELS`; also the user base of ``pip install --user``), then the system's."""
    import site

    envs = [sys.prefix, sys.base_prefix, site.getuserbase()]
    return list(dict.fromkeys([os.path.join(p, "lib") for p in envs] + list(SEARCH_DIRS)))

_PROBE = r"""
import drjit as dr
from drjit.llvm import Float
v = dr.detail.llvm_version()
if v[0] < 0:
    raise SystemExit("SPARSEBTF-LLVM-UNUSED")
if v[0] < 17:
    raise SystemExit(f"SPARSEBTF-LLVM-OLD {v[0]}.{v[1]}.{v[2]}")
x = dr.minimum(Float(1.0, 7.0, 3.0), 5.0)
x = dr.clip(x * 2.0, 0.0, 9.0)
assert x.numpy().tolist() == [2.0, 9.0, 6.0], x
print("SPARSEBTF-LLVM-OK", ".".join(str(i) for i in v))
"""


@dataclass
class LLVMStatus:
    """Outcome of the libLLVM search: the library used (if any) and what was tried."""

    path: str | None
    version: str | None
    tried: list[tuple[str, str]] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.path is not None

    def message(self) -> str:
        if self.ok:
            return f"Dr.Jit LLVM backend: {self.path} (LLVM {self.version})"
        lines = [f"no usable libLLVM for Dr.Jit's LLVM backend (sparsebtf needs LLVM >= "
                 f"{MIN_MAJOR})"]
        lines += [f"  {p}: {why}" for p, why in self.tried] or ["  no libLLVM found"]
        lines.append(
            "  install one without root: pip install karellen-llvm-core (or pip install "
            "'sparsebtf[render]'); as root: apt-get install libllvm19; or set "
            "DRJIT_LIBLLVM_PATH=/path/to/libLLVM.so"
        )
        return "\n".join(lines)


def _major(path: str) -> int | None:
    name = os.path.basename(path)
    m = re.search(r"LLVM[-.]?(?:so\.)?(\d+)", name)
    if m is None:
        m = re.search(r"(\d+)", name)
    return int(m.group(1)) if m else None


def candidate_libraries() -> list[str]:
    """libLLVM files of major version 17 or newer on this machine, best first
    (:data:`GOOD_MAJORS` in order, then newer majors, newest first)."""
    found: dict[int, list[str]] = {}
    for d in search_dirs():
        for pat in ("libLLVM.so.*", "libLLVM-*.so*", "libLLVM.dylib"):
            for path in sorted(glob.glob(os.path.join(d, pat))):
                major = _major(path)
                if major is not None and major >= MIN_MAJOR:
                    found.setdefault(major, []).append(os.path.realpath(path))
    newer = sorted((m for m in found if m not in GOOD_MAJORS), reverse=True)
    out: list[str] = []
    for major in (*GOOD_MAJORS, *newer):
        for p in found.get(major, []):
            if p not in out:
                out.append(p)
    return out


_probe_cache: dict[str, tuple[bool, str]] = {}


def probe_libllvm(path: str, timeout: float = 120.0) -> tuple[bool, str]:
    """Run a small Dr.Jit kernel with ``path`` in a subprocess: (works, version or reason).

    The subprocess protects this process: a bad libLLVM aborts the child, not us.
    """
    if path in _probe_cache:
        return _probe_cache[path]
    env = dict(os.environ, DRJIT_LIBLLVM_PATH=path)
    try:
        r = subprocess.run(
            [sys.executable, "-c", _PROBE],
            env=env,
            capture_output=True,
            text=True,
            timeout=timeout,
        )
    except subprocess.TimeoutExpired:
        res = (False, f"probe timed out after {timeout:.0f} s")
    except OSError as e:  # pragma: no cover - no python?
        res = (False, f"probe could not start: {e}")
    else:
        m = re.search(r"SPARSEBTF-LLVM-OK (\S+)", r.stdout)
        if r.returncode == 0 and m:
            res = (True, m.group(1))
        else:
            res = (False, _probe_failure(r.returncode, r.stdout, r.stderr))
    _probe_cache[path] = res
    return res


def _probe_failure(code: int, out: str, err: str) -> str:
    """One line on why a probe failed, in the terms of both Dr.Jit and this module."""
    old = re.search(r"SPARSEBTF-LLVM-OLD (\S+)", err) or re.search(
        r"located LLVM version \((\d+)\)", err
    )
    if old:
        return (f"LLVM {old.group(1)} is too old: sparsebtf needs LLVM >= {MIN_MAJOR} (Dr.Jit "
                "accepts 15, but 15 and 16 abort the process on some kernels)")  # fmt: skip
    load = re.search(r'Unable to load "[^"]*": (.*?)!?$', err, re.M)
    if load:
        return f"Dr.Jit cannot load it: {load.group(1)}"
    if "SPARSEBTF-LLVM-UNUSED" in err:
        lines = [x for x in err.splitlines() if "jit" in x.lower() and "SPARSEBTF" not in x]
        return "Dr.Jit did not start its LLVM backend with it" + (
            f": {lines[0].strip()}" if lines else ""
        )
    tail = (err or out).strip().splitlines()
    why = tail[-1] if tail else ""
    if code < 0:
        why = f"process killed by signal {-code} {why}".strip()
    return why or f"exit status {code}"


_status: LLVMStatus | None = None


def configure(force: bool = False) -> LLVMStatus:
    """Find and probe a libLLVM; export ``DRJIT_LIBLLVM_PATH`` if one works (cached).

    Call before ``import drjit``; once Dr.Jit is imported it keeps the library it loaded.
    ``SPARSEBTF_NO_LLVM=1`` disables the LLVM backend (the scalar fallback is used).
    """
    global _status
    if _status is not None and not force:
        return _status
    if os.environ.get("SPARSEBTF_NO_LLVM") == "1":
        _status = LLVMStatus(None, None, [("(all)", "disabled by SPARSEBTF_NO_LLVM=1")])
        return _status
    tried: list[tuple[str, str]] = []
    user = os.environ.get("DRJIT_LIBLLVM_PATH")
    candidates = [user] if user else candidate_libraries()
    for path in candidates:
        ok, info = probe_libllvm(path)
        if ok:
            os.environ["DRJIT_LIBLLVM_PATH"] = path
            _status = LLVMStatus(path, info, tried)
            return _status
        tried.append((path, info))
    if user:
        tried.append(("DRJIT_LIBLLVM_PATH", "set by the user and unusable; no other library tried"))
    _status = LLVMStatus(None, None, tried)
    return _status


_variant_cache: dict[str, tuple[str, str]] = {}


def _cuda_works() -> tuple[bool, str]:
    code = (
        "import drjit as dr\nfrom drjit.cuda import Float\n"
        "x = dr.minimum(Float(1.0, 7.0), 5.0)\nassert x.numpy().tolist() == [1.0, 5.0]\n"
        "print('SPARSEBTF-CUDA-OK')\n"
    )
    try:
        r = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, timeout=180
        )
    except (subprocess.TimeoutExpired, OSError) as e:
        return False, str(e)
    if r.returncode == 0 and "SPARSEBTF-CUDA-OK" in r.stdout:
        return True, "CUDA backend works"
    tail = (r.stderr or r.stdout).strip().splitlines()
    return False, tail[-1] if tail else f"exit status {r.returncode}"


def choose_variant(prefer: str = "auto") -> tuple[str, str]:
    """The Mitsuba variant to use and a one-line reason: ``(variant, message)``.

    ``prefer``: ``"auto"`` (llvm, else scalar), ``"cuda"`` (GPU if it works, else as auto),
    ``"llvm"`` (llvm or scalar with the reason), ``"scalar"``.
    """
    if prefer in _variant_cache:
        return _variant_cache[prefer]
    if prefer not in ("auto", "cuda", "llvm", "scalar"):
        from .errors import BTFInputError

        raise BTFInputError(f"unknown backend {prefer!r}; choose auto, cuda, llvm or scalar")
    if prefer == "scalar":
        out = ("scalar_rgb", "scalar_rgb requested")
    else:
        res: tuple[str, str] | None = None
        if prefer == "cuda":
            ok, why = _cuda_works()
            if ok:
                res = ("cuda_ad_rgb", why)
        if res is None:
            st = configure()
            if st.ok:
                res = ("llvm_ad_rgb", st.message())
            else:
                res = (
                    "scalar_rgb",
                    st.message() + "\n  falling back to the scalar_rgb variant: the BSDF runs "
                    "in Python per ray, so keep renders tiny (e.g. 32x32, 4 spp)",
                )
        out = res
    _variant_cache[prefer] = out
    return out


# The scalar-fallback warning is printed once per process, not at every render.
_warned: list[str] = []


def activate_variant(backend: str = "auto", quiet: bool = False) -> tuple[str, str]:
    """Choose (:func:`choose_variant`) and set a Mitsuba variant: ``(variant, message)``.

    With a variant already active and ``backend="auto"`` that variant is kept. Falling back to
    ``scalar_rgb`` when llvm was wanted prints why on stderr, once, unless ``quiet``.
    """
    variant, why = choose_variant(backend)
    import mitsuba as mi

    current = mi.variant()
    if current is None or backend != "auto":
        if current != variant:
            mi.set_variant(variant)
        if variant == "scalar_rgb" and backend != "scalar" and not quiet and not _warned:
            _warned.append(why)
            print(f"sparsebtf.mitsuba: {why}", file=sys.stderr)
        return variant, why
    if current != variant:
        return current, f"keeping the active Mitsuba variant {current}"
    return current, why
