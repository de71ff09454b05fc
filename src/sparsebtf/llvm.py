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
imported, because Dr.Jit reads the variable once, while ``import drjit`` runs.
``DRJIT_LIBLLVM_PATH`` set by the user overrides the search (it is still probed); one set by the
installed start-up hook (:mod:`sparsebtf._llvm_startup`, marked by ``SPARSEBTF_DRJIT_LLVM_AUTO``)
is the first candidate. Results are cached per process.

Once ``drjit`` is imported (a script that began with ``import mitsuba``), its library is fixed:
:func:`configure` then reports the libLLVM the process actually mapped (``/proc/self/maps``) and
the version Dr.Jit reports, and when that is older than 17, :func:`choose_variant` raises
:class:`LLVMImportOrderError`, one line naming the loaded library and a usable one to set in
``DRJIT_LIBLLVM_PATH`` — before a kernel could abort the process.

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
    "LLVMImportOrderError",
    "LLVMStatus",
    "candidate_libraries",
    "choose_variant",
    "configure",
    "loaded_libllvm",
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
#: Holds the path when the start-up hook (:mod:`sparsebtf._llvm_startup`), not the user, set
#: ``DRJIT_LIBLLVM_PATH``.
AUTO_MARK = "SPARSEBTF_DRJIT_LLVM_AUTO"


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
    #: True when read from a Dr.Jit already imported (the library it loaded), not a search.
    loaded: bool = False
    #: Set when Dr.Jit already loaded a libLLVM < MIN_MAJOR: the one-line error and its fix.
    blocked: str | None = None

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


class LLVMImportOrderError(ImportError):
    """Dr.Jit was imported (e.g. by ``import mitsuba``) before ``sparsebtf.mitsuba`` and loaded
    a libLLVM that aborts the process on the plugins' kernels; the message (one line) names it
    and the fix."""


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


def loaded_libllvm(major: int | None = None) -> str | None:
    """The libLLVM file mapped into this process (``/proc/self/maps``), or None.

    With ``major``, the mapped one of that major version (a process may map another libLLVM
    for something else, e.g. Mesa's); None where ``/proc`` is missing (macOS).
    """
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as f:
            lines = f.read().splitlines()
    except OSError:
        return None
    paths = dict.fromkeys(
        p for p in (line.split(maxsplit=5)[-1] for line in lines if "libLLVM" in line)
        if os.path.basename(p).startswith("libLLVM")
    )  # fmt: skip
    for p in paths:
        if major is None or _major(p) == major:
            return p
    return None


def _usable_elsewhere(loaded: str | None) -> str | None:
    """The first library of the search (:func:`candidate_libraries`) that passes the probe,
    other than ``loaded``: what to set ``DRJIT_LIBLLVM_PATH`` to."""
    skip = os.path.realpath(loaded) if loaded else None
    for path in candidate_libraries():
        if path != skip and probe_libllvm(path)[0]:
            return path
    return None


def _fix(usable: str | None) -> str:
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if usable and env and env != os.environ.get(AUTO_MARK):  # the user's own choice loaded
        return (f"DRJIT_LIBLLVM_PATH is set to {env}: set it to {usable} instead, before Python "
                "starts")  # fmt: skip
    if usable:
        return (f"set DRJIT_LIBLLVM_PATH={usable} before Python starts (or before the first "
                "import of mitsuba or drjit), or import sparsebtf.mitsuba first")  # fmt: skip
    return ("install one (pip install 'sparsebtf[render]', no root; or apt-get install "
            "libllvm19) and set DRJIT_LIBLLVM_PATH=/path/to/libLLVM.so before Python starts")


def _loaded_status() -> LLVMStatus:
    """What the already imported Dr.Jit loaded: its version and the mapped file."""
    import drjit as dr

    v = tuple(int(x) for x in dr.detail.llvm_version())
    if v[0] < 0:
        why = ("Dr.Jit was imported before sparsebtf and found no libLLVM, so its LLVM "
               f"backend is off in this process; {_fix(_usable_elsewhere(None))}")  # fmt: skip
        return LLVMStatus(None, None, [("(Dr.Jit)", why)], loaded=True)
    version = ".".join(str(i) for i in v)
    path = loaded_libllvm(v[0]) or loaded_libllvm() or "(path unknown)"
    if v[0] >= MIN_MAJOR:
        return LLVMStatus(path, version, [], loaded=True)
    blocked = (
        f"Dr.Jit was imported before sparsebtf.mitsuba and loaded LLVM {version} ({path}), which "
        f"aborts the process on the first kernel of a scene (sparsebtf needs LLVM >= "
        f"{MIN_MAJOR}): {_fix(_usable_elsewhere(path))}"
    )
    return LLVMStatus(None, None, [(path, f"LLVM {version} loaded by Dr.Jit is too old")],
                      loaded=True, blocked=blocked)  # fmt: skip


_status: LLVMStatus | None = None


def configure(force: bool = False) -> LLVMStatus:
    """Find and probe a libLLVM; export ``DRJIT_LIBLLVM_PATH`` if one works (cached).

    Call before ``import drjit``; once Dr.Jit is imported it keeps the library it loaded, and
    this returns that library (``loaded``; ``blocked`` when it is older than 17).
    ``SPARSEBTF_NO_LLVM=1`` disables the LLVM backend (the scalar fallback is used).
    """
    global _status
    drjit_in = "drjit" in sys.modules
    if _status is not None and not force and (_status.loaded or not drjit_in):
        return _status
    if os.environ.get("SPARSEBTF_NO_LLVM") == "1":
        _status = LLVMStatus(None, None, [("(all)", "disabled by SPARSEBTF_NO_LLVM=1")])
        return _status
    if drjit_in:
        _status = _loaded_status()
        return _status
    tried: list[tuple[str, str]] = []
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    # The start-up hook's choice is a first candidate, not the user's word.
    user = env if env and env != os.environ.get(AUTO_MARK) else None
    candidates = [user] if user else list(dict.fromkeys([*([env] if env else []),
                                                         *candidate_libraries()]))  # fmt: skip
    for path in candidates:
        ok, info = probe_libllvm(path)
        if ok:
            os.environ["DRJIT_LIBLLVM_PATH"] = path
            if not user:
                os.environ[AUTO_MARK] = path
            _status = LLVMStatus(path, info, tried)
            return _status
        tried.append((path, info))
    if user:
        tried.append(("DRJIT_LIBLLVM_PATH", "set by the user and unusable; no other library tried"))
    _status = LLVMStatus(None, None, tried)
    return _status


_cuda_cache: list[tuple[bool, str]] = []


def _cuda_works() -> tuple[bool, str]:
    if _cuda_cache:
        return _cuda_cache[0]
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
        res = (False, str(e))
    else:
        tail = (r.stderr or r.stdout).strip().splitlines()
        res = ((True, "CUDA backend works") if r.returncode == 0 and "SPARSEBTF-CUDA-OK" in r.stdout
               else (False, tail[-1] if tail else f"exit status {r.returncode}"))  # fmt: skip
    _cuda_cache.append(res)
    return res


def choose_variant(prefer: str = "auto") -> tuple[str, str]:
    """The Mitsuba variant to use and a one-line reason: ``(variant, message)``.

    ``prefer``: ``"auto"`` (llvm, else scalar), ``"cuda"`` (GPU if it works, else as auto),
    ``"llvm"`` (llvm or scalar with the reason), ``"scalar"``. The message names the libLLVM
    Dr.Jit uses: the one it loaded once ``drjit`` is imported (:func:`configure`).

    Raises :class:`LLVMImportOrderError` instead of choosing when llvm (or its scalar fallback)
    would be chosen but Dr.Jit already loaded a libLLVM older than 17.
    """
    if prefer not in ("auto", "cuda", "llvm", "scalar"):
        from .errors import BTFInputError

        raise BTFInputError(f"unknown backend {prefer!r}; choose auto, cuda, llvm or scalar")
    if prefer == "scalar":
        return "scalar_rgb", "scalar_rgb requested"
    if prefer == "cuda":
        ok, why = _cuda_works()
        if ok:
            return "cuda_ad_rgb", why
    st = configure()
    if st.blocked:
        raise LLVMImportOrderError(st.blocked)
    if st.ok:
        return "llvm_ad_rgb", st.message()
    return (
        "scalar_rgb",
        st.message() + "\n  falling back to the scalar_rgb variant: the BSDF runs "
        "in Python per ray, so keep renders tiny (e.g. 32x32, 4 spp)",
    )


# The scalar-fallback warning is printed once per process, not at every render.
_warned: list[str] = []


def activate_variant(backend: str = "auto", quiet: bool = False) -> tuple[str, str]:
    """Choose (:func:`choose_variant`) and set a Mitsuba variant: ``(variant, message)``.

    With a variant already active and ``backend="auto"`` that variant is kept; an active
    ``llvm_*`` variant is checked against the libLLVM Dr.Jit loaded (:class:`LLVMImportOrderError`
    when older than 17). Falling back to ``scalar_rgb`` when llvm was wanted prints why on
    stderr, once, unless ``quiet``.
    """
    mi = sys.modules.get("mitsuba")  # a variant can only be active once mitsuba is imported
    current = mi.variant() if mi is not None else None
    if current is not None and backend == "auto" and not current.startswith("llvm_"):
        return current, f"keeping the active Mitsuba variant {current}"
    variant, why = choose_variant(backend)
    import mitsuba as mi

    if variant.startswith("llvm_"):
        st = configure()  # drjit is imported now: name the library it actually loaded
        if st.blocked:
            raise LLVMImportOrderError(st.blocked)
        why = st.message() if st.ok else why
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
