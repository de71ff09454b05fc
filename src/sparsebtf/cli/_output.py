"""How every command prints: one JSON object (``--json``, for machines) or, for people, a
two-column table with words for keys and readable values (no raw dicts, no ``snake_case``).
Results with NaN or infinity are refused (one error line) unless ``--allow-nonfinite`` is given.

Keys without an entry in :data:`LABELS` still read as words (``bytes_stats`` → "bytes
stats"), so a field a library result gains later prints without a change here.
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from .._json import json_default
from ..errors import SparseBTFError

__all__ = [
    "LABELS", "Written", "add_allow_nonfinite", "announce_size", "check_finite_result",
    "dense_bytes", "format_value", "label", "nested_rows", "print_json", "table",
]  # fmt: skip

#: Words (and units) for the keys of library results that commands print as tables.
LABELS = {
    "bytes_raw": "raw bytes (fp16)",
    "bytes_raw_float32": "raw bytes (float32)",
    "bytes_values": "coefficient value bytes",
    "bytes_locations": "coefficient location bytes",
    "bytes_coefficients": "coefficient bytes (paper Table 4)",
    "bytes_membership_counts": "membership and count bytes",
    "bytes_dictionaries": "dictionary bytes (shared by every material)",
    "bytes_stats": "statistics bytes",
    "bytes_stats_release": "statistics bytes in the release's layout",
    "bytes_total": "total bytes",
    "mib_total": "total MiB",
    "raw_bytes_fp16": "raw bytes (fp16)",
    "compression_ratio": "ratio with dictionaries",
    "compression_ratio_per_material": "ratio per material",
    "file_bytes": "file bytes",
    "nnz": "coefficients",
    "content_hash": "content hash",
    "model_hash": "model hash",
    "mode_sizes": "data point (mode sizes)",
    "n_dictionaries": "dictionaries per ensemble (K)",
    "value_range": "value range",
    "nonfinite": "non-finite values",
    "mse_rgb": "MSE, linear RGB",
    "mse_log": "MSE, log RGB",
    "mse_display": "MSE, display-mapped",
    "mse_std": "MSE, standardised",
    "mse_std_codes": "MSE, standardised, from the codes",
    "psnr_rgb": "PSNR, linear RGB",
    "ssim": "SSIM",
    "peak": "PSNR peak",
    "ssim_images": "SSIM angular images",
    "max_decoded": "largest decoded value",
    "reference_max": "largest reference value",
    "top_error_share": "worst 0.01 % of values",
    "ssim_data_range": "SSIM data range",
    "tau": "tau",
    "tau_train": "training tau",
    "std_mode": "standardisation",
    "eps": "eps",
}


def label(key: str) -> str:
    """The words for ``key``: :data:`LABELS`, else the key with spaces for underscores."""
    return LABELS.get(key, key.replace("_", " "))


def format_value(v: Any, group: bool = True) -> str:
    """A value as a person reads it: 4 significant digits, thousands separators (``group``;
    not inside lists, where the commas separate the items), ``{ch: n}`` as ``Y 885, U 64,
    V 64``, lists comma-separated, None as "none"."""
    if v is None:
        return "none"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        if math.isfinite(v) and v.is_integer() and abs(v) < 1e15:
            return f"{int(v):,}" if group and abs(v) >= 1000 else str(int(v))
        if 100 <= abs(v) < 1e9:  # 2697.8, not 2698
            return f"{v:,.1f}" if group else f"{v:.1f}"
        return f"{v:.4g}"
    if isinstance(v, int):
        return f"{v:,}" if group and abs(v) >= 1000 else str(v)
    if isinstance(v, Mapping):
        if all(not isinstance(x, Mapping | list | tuple) for x in v.values()):
            return ", ".join(f"{k} {format_value(x)}" for k, x in v.items()) or "(none)"
        return json.dumps(v, default=json_default)
    if isinstance(v, list | tuple):
        if len(v) > 12:
            return f"[{len(v)} values: {format_value(v[0], False)} … {format_value(v[-1], False)}]"
        return ", ".join(format_value(x, False) for x in v) or "(none)"
    try:  # NumPy scalars
        return format_value(v.item(), group)
    except AttributeError:
        return str(v)


def nested_rows(obj: Mapping[str, Any], prefix: str = "") -> list[tuple[str, str]]:
    """A nested result as table rows: nested keys joined by '.', each part in words; a
    ``{channel: number}`` mapping on one row; direction tables as "151 (ubo2014)"."""
    rows: list[tuple[str, str]] = []
    for k, v in obj.items():
        key = f"{prefix}{label(str(k))}"
        if isinstance(v, Mapping) and set(v) == {"name", "count"}:
            rows.append((key, f"{v['count']} ({v['name']})"))
        elif isinstance(v, Mapping) and v and (
            any(isinstance(x, Mapping | list | tuple | str) for x in v.values())
            or any(len(str(x)) > 3 for x in v)  # one row only for {channel: number}
        ):
            rows += nested_rows(v, key + ".")
        else:
            rows.append((key, format_value(v)))
    return rows


def dense_bytes(btf: Any, dtype: str = "float32") -> int:
    """Bytes of the dense file (:func:`sparsebtf.data.dense_file.write_dense`) of ``btf`` at
    ``dtype``: its stored chunks (the header and direction tables add a few KiB)."""
    from ..data.dense_file import dense_file_bytes

    return dense_file_bytes(btf.shape, dtype)


def announce_size(path: Any, nbytes: int, what: str, file: TextIO | None = None) -> None:
    """One line before a large write, so a user can stop it: ``writing X: 1.05 GiB (what)``."""
    from .._limits import format_bytes

    print(f"writing {path}: {format_bytes(nbytes)} ({what})", file=file or sys.stdout,
          flush=True)  # fmt: skip


class Written:
    """What a command that writes files says: ``writing …`` before each large file and
    ``wrote …`` after, for people; with ``--json`` one object ``{"written": [{"path",
    "file_bytes", …}]}`` at the end (the ``writing`` lines then go to stderr, so stdout
    holds only the JSON)."""

    def __init__(self, as_json: bool) -> None:
        self.as_json = as_json
        self.files: list[dict[str, Any]] = []

    def announce(self, path: Any, nbytes: int, what: str) -> None:
        announce_size(path, nbytes, what, sys.stderr if self.as_json else sys.stdout)

    def wrote(self, path: Any, text: str = "", **fields: Any) -> None:
        """Record a finished file (``fields`` go into its JSON entry) and say so."""
        self.files.append({"path": str(path), "file_bytes": Path(path).stat().st_size,
                           **fields})  # fmt: skip
        if not self.as_json:
            print(f"wrote {path}{': ' + text if text else ''}")

    def finish(self) -> None:
        if self.as_json:
            print_json({"written": self.files})


#: The one flag, the same in every command that prints numbers.
ALLOW_NONFINITE = "--allow-nonfinite"


def add_allow_nonfinite(parser: Any) -> None:
    """Add ``--allow-nonfinite`` to a command that prints numeric results."""
    parser.add_argument(
        ALLOW_NONFINITE, action="store_true",
        help="print results even when some are NaN or infinite (default: an error, exit 2)",
    )  # fmt: skip


def _numbers(obj: Any, key: str) -> Iterator[tuple[str, float]]:
    """Every number in a nested dict / list / array, with its key path."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _numbers(v, f"{key}.{k}" if key else str(k))
    elif isinstance(obj, list | tuple):
        for i, v in enumerate(obj):
            yield from _numbers(v, f"{key}[{i}]")
    elif isinstance(obj, np.ndarray) and obj.dtype.kind in "fc":
        bad = ~np.isfinite(obj)
        if bad.any():
            i = tuple(int(x[0]) for x in np.nonzero(bad))
            yield f"{key}{list(i)}", float(obj[i])
    elif isinstance(obj, float | np.floating) and not isinstance(obj, bool):
        yield key, float(obj)


def check_finite_result(
    obj: Any, command: str, allow: bool = False, exact: tuple[str, ...] = ()
) -> None:
    """Refuse a result holding NaN or ±inf (one line naming the first such field), unless
    ``allow`` (the user gave ``--allow-nonfinite``). ``exact`` names fields whose +inf is the
    exact answer (the PSNR of identical images)."""
    if allow:
        return
    bad = [(k, v) for k, v in _numbers(obj, "")
           if not math.isfinite(v) and not (k in exact and v == math.inf)]  # fmt: skip
    if bad:
        key, value = bad[0]
        raise SparseBTFError(
            f"{command}: the result {key} is {value} ({len(bad)} non-finite numbers): the "
            f"decoded values overflow or an input is damaged; {ALLOW_NONFINITE} prints it anyway"
        )


def print_json(obj: Any) -> None:
    """``obj`` as indented JSON on stdout (NumPy values and paths converted)."""
    print(json.dumps(obj, indent=2, sort_keys=True, default=json_default))


def table(rows: list[tuple[str, Any]]) -> str:
    """Aligned ``key  value`` lines."""
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)
