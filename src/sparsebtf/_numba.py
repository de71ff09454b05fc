"""numba when it is installed (and not disabled with ``SPARSEBTF_NO_NUMBA=1``), else None.

Every compiled kernel has a NumPy twin that is the reference; tests tie the two together.
"""

from __future__ import annotations

import os
from types import ModuleType

__all__ = ["HAVE_NUMBA", "numba"]

numba: ModuleType | None
try:  # numba is optional: the NumPy paths are complete on their own.
    if os.environ.get("SPARSEBTF_NO_NUMBA"):
        raise ImportError("disabled by SPARSEBTF_NO_NUMBA")
    import numba
except ImportError:  # pragma: no cover - depends on the environment
    numba = None

HAVE_NUMBA = numba is not None
