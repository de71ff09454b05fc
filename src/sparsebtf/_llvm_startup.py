"""Start-up hook: point Dr.Jit at the ``render`` extra's libLLVM before any script imports it.

Dr.Jit loads its libLLVM while ``import drjit`` runs, and reads ``DRJIT_LIBLLVM_PATH`` only
then. Without the variable it loads the system's library: Debian 12's is LLVM 15, which aborts
the whole process (``LLVM ERROR: Cannot select … fminimum``, exit 134) on the first kernel of an
ordinary scene. A script that starts with ``import mitsuba`` reaches Dr.Jit before
``sparsebtf.mitsuba`` could set the variable (docs/rendering.md, "Import order").

So the build (``setup.py``) copies this file's source into ``sparsebtf-drjit-llvm.pth`` at the
top of ``site-packages``, which Python's ``site`` module runs at every interpreter start. When
``DRJIT_LIBLLVM_PATH`` is not set, it sets it to a libLLVM of major version
>= :data:`MIN_MAJOR` installed by pip into the ``lib/`` folder of an installation scheme (the
``karellen-llvm-core`` wheel of the ``render`` extra puts ``libLLVM.so.23.1`` there, beside
the ``site-packages`` it was installed with: ``site-packages/../../``), and records the path in
:data:`MARK` so :mod:`sparsebtf.llvm` can tell it from a path the user chose. A variable the
user set, even to an empty string, is never touched; ``SPARSEBTF_LLVM_HOOK=0`` turns the hook
off.

It must stay cheap and self-contained: standard library only, no import of ``sparsebtf``
(whose package imports NumPy and more), no probe. One ``listdir`` per candidate folder.
"""

import os
import sys

#: The variable Dr.Jit reads when ``drjit`` is imported.
ENV = "DRJIT_LIBLLVM_PATH"
#: Set to the same path when this hook (not the user) chose ``DRJIT_LIBLLVM_PATH``.
MARK = "SPARSEBTF_DRJIT_LLVM_AUTO"
#: ``SPARSEBTF_LLVM_HOOK=0`` turns this hook off.
OFF = "SPARSEBTF_LLVM_HOOK"
#: LLVM 15 and 16 abort the process on some kernels (sparsebtf.llvm); never point Dr.Jit there.
MIN_MAJOR = 17


def _major(name):
    """Major version of a file named ``libLLVM.so.N.M`` or ``libLLVM-N.so``, else -1."""
    if name.startswith("libLLVM.so."):
        head = name[len("libLLVM.so.") :].split(".")[0]
    elif name.startswith("libLLVM-") and name.endswith(".so"):
        head = name[len("libLLVM-") : -len(".so")]
    else:
        return -1
    return int(head) if head.isdigit() else -1


def lib_dirs(sitedir=None):
    """Folders searched, in order: ``sitedir/../..`` (the scheme this file was installed in),
    then ``lib/`` of ``sys.prefix``, ``sys.base_prefix`` and the user base."""
    user = getattr(sys.modules.get("site"), "USER_BASE", None)
    out = [os.path.normpath(os.path.join(sitedir, "..", ".."))] if sitedir else []
    out += [os.path.join(p, "lib") for p in (sys.prefix, sys.base_prefix, user) if p]
    return list(dict.fromkeys(out))


def find(dirs):
    """The newest libLLVM >= :data:`MIN_MAJOR` in the first folder of ``dirs`` holding one."""
    for d in dirs:
        try:
            names = os.listdir(d)
        except OSError:
            continue
        best = max(((_major(n), n) for n in names), default=(-1, ""))
        if best[0] >= MIN_MAJOR:
            return os.path.join(d, best[1])
    return None


def main(sitedir=None, environ=None):
    """Set ``DRJIT_LIBLLVM_PATH`` (and :data:`MARK`) unless it is set; the path set, or None."""
    environ = os.environ if environ is None else environ
    if ENV in environ or environ.get(OFF) == "0":
        return None
    path = find(lib_dirs(sitedir))
    if path is not None:
        environ[ENV] = path
        environ[MARK] = path
    return path


if __name__ == "__pth__":  # run from the .pth line (setup.py): never break interpreter start
    try:
        main(_sitedir)  # noqa: F821 - given by the .pth line
    except Exception:
        pass
