"""Build step: ship ``sparsebtf-drjit-llvm.pth`` at the top of site-packages.

Everything else is configured in pyproject.toml. The ``.pth`` file runs
``src/sparsebtf/_llvm_startup.py`` at interpreter start, so that Dr.Jit finds the ``render``
extra's libLLVM however a user's script begins (docs/rendering.md, "Import order"). The module's
source is embedded in the one ``import`` line of the ``.pth`` (run by ``site``), so the hook does
not depend on where, or whether yet, the package is importable.

A normal build puts the file into ``build_lib`` (the wheel's root, i.e. site-packages); an
editable install (PEP 660) has no build_lib in the wheel, so it goes to the unpacked editable
wheel, where setuptools puts the files that are installed as they are (``install_lib``).
"""

from __future__ import annotations

import ast
import os

from setuptools import setup
from setuptools.command.build_py import build_py

PTH_NAME = "sparsebtf-drjit-llvm.pth"
ROOT = os.path.dirname(os.path.abspath(__file__))
HOOK = os.path.join(ROOT, "src", "sparsebtf", "_llvm_startup.py")


def _without_docstrings(source: str) -> str:
    """``source`` re-written by ``ast`` without docstrings or comments: less to compile at
    every interpreter start (the hook's cost is mostly ``compile``)."""
    tree = ast.parse(source)
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        first = body[0] if isinstance(body, list) and body else None
        if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
            if isinstance(first.value.value, str):
                body[:] = body[1:] or [ast.Pass()]
    return ast.unparse(tree)


def pth_line(source: str) -> str:
    """The ``.pth`` line. ``site`` executes lines starting with ``import``; ``sitedir`` is a
    local of ``site.addpackage`` (the folder the ``.pth`` lies in). With ``DRJIT_LIBLLVM_PATH``
    set, or ``SPARSEBTF_LLVM_HOOK=0``, the line stops before compiling anything."""
    ns = '{"__name__": "__pth__", "_sitedir": locals().get("sitedir")}'
    code = repr(_without_docstrings(source))
    return (
        f"import os, sys; 'DRJIT_LIBLLVM_PATH' in os.environ or "
        "os.environ.get('SPARSEBTF_LLVM_HOOK') == '0' or "
        f"exec(compile({code}, {PTH_NAME!r}, 'exec'), {ns})\n"
    )


class BuildPyWithPth(build_py):
    def run(self) -> None:
        super().run()
        with open(HOOK, encoding="utf-8") as f:
            line = pth_line(f.read())
        if getattr(self, "editable_mode", False):
            target = self.get_finalized_command("install").install_lib
        else:
            target = self.build_lib
        os.makedirs(target, exist_ok=True)
        with open(os.path.join(target, PTH_NAME), "w", encoding="utf-8") as f:
            f.write(line)

    def get_outputs(self, include_bytecode: bool = True) -> list[str]:
        extra = [os.path.join(self.build_lib, PTH_NAME)]
        if getattr(self, "editable_mode", False):
            extra = []  # not in build_lib (above); the editable wheel lists it itself
        return [*super().get_outputs(include_bytecode), *extra]


if __name__ == "__main__":  # setuptools runs this file as __main__; tests import pth_line
    setup(cmdclass={"build_py": BuildPyWithPth})
