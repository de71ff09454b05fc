"""Storage accounting: the paper's Table 4 bytes (the release's ``btf4Dcomp``) and the bytes
a coded file actually stores, side by side.

Table 4 (paper): per channel the bytes of :func:`sparsebtf.learning.cost.channel_storage`
(values, locations, dictionaries, membership and counts). Raw size is H·W·L·V·3 values at
2 bytes (binary16). ``bytes_total`` = coefficients + membership/counts + dictionaries and
``compression_ratio`` = raw / ``bytes_total``, as the paper counts them: for UBO2014 at
τ = (885, 64, 64), K = 8 and 1600 points per channel, 10,312,096 B ≈ 9.83 MiB, ratio ≈ 2122.6
(Table 4's 2122). ``bytes_table4_material`` leaves out the dictionaries, which the model
shares with every material (``compression_ratio_table4_material``). Table 4 counts neither the
standardisation statistics nor the direction tables a material needs.

Stored: the bytes of the coded file, by what they hold: ``bytes_stored_codes`` (every dataset
of ``codes/``), ``bytes_stored_stats`` (``stats/``), ``bytes_stored_directions`` (``lights/``,
``views/``) and ``bytes_stored_header`` (the rest: HDF5 structure, attributes, chunk indexes),
which sum to ``bytes_stored``, the file's size: everything a material needs beyond the shared
model. ``compression_ratio_per_material`` = raw / ``bytes_stored``. Without a file the coded
BTF is written in memory to measure them (:func:`~sparsebtf.storage.coded_file.coded_image`).
"""

from __future__ import annotations

import io
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import h5py

from .._hdf5 import open_h5
from ..errors import BTFInputError, ModelMismatchError
from ..learning.cost import channel_storage, raw_bytes
from ..model import CHANNELS, CodedBTF, Model, model_text

__all__ = [
    "MIB", "STORED_PARTS", "paper_storage", "storage_report", "storage_summary", "stored_bytes",
]  # fmt: skip

#: Bytes per MiB (the paper reports sizes in MiB = 2^20 bytes).
MIB = float(1 << 20)


#: Top-level groups of a coded file → the part of ``bytes_stored`` they count in.
STORED_PARTS = {"codes": "codes", "stats": "stats", "lights": "directions", "views": "directions",
                # schema 4 (adaptive patch sizes): the codes by size and the tree
                "sizes": "codes", "tree": "codes",
                # schema 5: the highlight store is part of the material's codes
                "highlights": "codes"}


def stored_bytes(source: str | os.PathLike[str] | bytes) -> dict[str, int]:
    """Bytes a coded file stores, by part: ``bytes_stored_codes``, ``_stats``, ``_directions``
    (the datasets' stored, i.e. compressed, sizes), ``_header`` (the rest of the file) and
    ``bytes_stored`` (the file's size, their sum). ``source``: a path or a file image."""
    if isinstance(source, bytes):
        size = len(source)
        f = h5py.File(io.BytesIO(source), "r")
    else:
        size = Path(source).stat().st_size
        f = open_h5(source)
    parts = dict.fromkeys(("codes", "stats", "directions"), 0)
    with f:
        def visit(name: str, obj: Any) -> None:
            part = STORED_PARTS.get(name.split("/")[0])
            if part is not None and isinstance(obj, h5py.Dataset):
                parts[part] += int(obj.id.get_storage_size())

        f.visititems(visit)
    out = {f"bytes_stored_{k}": v for k, v in parts.items()}
    out["bytes_stored_header"] = size - sum(parts.values())
    out["bytes_stored"] = size
    return out


def _combine(
    per_channel: dict[str, dict[str, Any]],
    height: int, width: int, n_lights: int, n_views: int,
    bytes_stats: int, stored: dict[str, int] | None, bytes_highlights: int = 0,
) -> dict[str, Any]:
    raw_values = height * width * n_lights * n_views * 3
    coeff = sum(c["bytes_coefficients"] for c in per_channel.values())
    dicts = sum(c["bytes_dictionaries"] for c in per_channel.values())
    mz = sum(c["bytes_membership"] + c["bytes_counts"] for c in per_channel.values())
    hl = int(bytes_highlights)
    material = coeff + mz + hl
    total = material + dicts
    raw = raw_bytes(raw_values)
    out: dict[str, Any] = {
        "bytes_raw": raw,
        "bytes_raw_float32": 4 * raw_values,
        "bytes_values": sum(c["bytes_values"] for c in per_channel.values()),
        "bytes_locations": sum(c["bytes_locations"] for c in per_channel.values()),
        "bytes_coefficients": coeff,
        "bytes_membership_counts": mz,
        # the highlight store (Highlights.nbytes: its compact code, or 9-byte entries)
        "bytes_highlights": hl,
        "bytes_table4_material": material,
        "bytes_dictionaries": dicts,
        "bytes_total": total,
        "mib_total": total / MIB,
        "compression_ratio": raw / total if total else float("inf"),
        "compression_ratio_table4_material": raw / material if material else float("inf"),
        "bytes_stats": int(bytes_stats),
        "nnz": {ch: c["nnz"] for ch, c in per_channel.items()},
    }
    if stored is not None:
        out.update(stored)
        out["compression_ratio_per_material"] = raw / stored["bytes_stored"]
        out["stored_codes_vs_table4"] = (
            stored["bytes_stored_codes"] / material if material else float("nan")
        )
    out["channels"] = per_channel
    return out


def paper_storage(
    height: int,
    width: int,
    n_lights: int,
    n_views: int,
    patch: int,
    tau_per_channel: Sequence[int] | Mapping[str, int],
    n_dictionaries: int,
) -> dict[str, Any]:
    """Table 4 storage of a BTF coded with exactly τ coefficients in every point.

    ``tau_per_channel`` is a mapping channel → τ or a sequence in the order Y, U, V. The
    returned dict has the Table 4 keys of :func:`storage_report` (``bytes_stats`` is our
    float32 shared statistics, ``file_bytes`` is None; nothing is stored, so no stored keys).
    Example: ``paper_storage(400, 400, 151, 151, 10, (885, 64, 64), 8)["bytes_total"] ==
    10_312_096`` (9.83 MiB, ratio ≈ 2122.6).
    """
    if isinstance(tau_per_channel, Mapping):
        taus = {str(k): int(v) for k, v in tau_per_channel.items()}
    else:
        seq = [int(t) for t in tau_per_channel]
        if not 1 <= len(seq) <= len(CHANNELS):
            raise BTFInputError(f"give one τ per channel (Y, U, V), got {len(seq)}")
        taus = dict(zip(CHANNELS, seq, strict=False))
    if patch < 1 or height % patch or width % patch:
        raise BTFInputError(f"size {height}x{width} is not a multiple of the patch {patch}")
    n_points = (height // patch) * (width // patch)
    sizes = (patch, patch, n_lights, n_views)
    per = {
        ch: channel_storage(tau * n_points, n_points, n_dictionaries, sizes)
        for ch, tau in taus.items()
    }
    out = _combine(per, height, width, n_lights, n_views, 2 * 4 * n_lights * n_views, None)
    out["file_bytes"] = None
    return out


def storage_report(
    coded: CodedBTF,
    model: Model | None = None,
    file_path: str | os.PathLike[str] | None = None,
    *,
    stored: bool = True,
) -> dict[str, Any]:
    """Storage of a coded BTF: the paper's Table 4 bytes and the bytes actually stored.

    K (for the dictionary bytes) comes from ``model`` (or the model attached to ``coded``);
    without one, from ``coded.params["n_dictionaries"]`` (an int, or a dict per channel);
    failing that, from ``max(membership) + 1`` — a lower bound. Each channel's
    ``dictionary_source`` says which was used. Mode sizes are those of the codes.

    Table 4 keys: ``bytes_raw``, ``bytes_raw_float32``, ``bytes_values``, ``bytes_locations``,
    ``bytes_coefficients`` (values + locations), ``bytes_membership_counts``,
    ``bytes_table4_material`` (coefficients + membership/counts), ``bytes_dictionaries``
    (shared by every material on the model), ``bytes_total`` (material + dictionaries),
    ``mib_total``, ``compression_ratio`` (raw / total), ``compression_ratio_table4_material``,
    ``nnz`` (channel → count), ``channels`` (per-channel :func:`channel_storage`).
    ``bytes_stats``: the statistics as float32 arrays, before compression.

    Stored keys (unless ``stored=False``), of ``file_path`` or, without one, of the file
    :func:`~sparsebtf.storage.save_coded` would write: those of :func:`stored_bytes`,
    ``compression_ratio_per_material`` (raw / ``bytes_stored``), ``stored_codes_vs_table4``
    (stored codes / Table 4's material bytes). ``file_bytes`` is the size of ``file_path``
    (None without one). ``bytes_model_file``: the size of the model's file, when known (the
    part shared with every material on it).
    """
    m = model if model is not None else coded.model
    if m is not None and m.content_hash != coded.model_hash:
        raise ModelMismatchError(
            f"{coded.label}: coded with {model_text(coded.model_hash, coded.model_file)}, but "
            f"the given model is {model_text(m.content_hash, m.file)}"
        )
    per: dict[str, dict[str, Any]] = {}
    for ch in coded.channels:
        c = coded.codes[ch]
        known = coded.dictionary_count(ch, m)
        if known is not None:
            k, source = known, "model" if m is not None and ch in m.dictionaries else "params"
        else:
            k = int(c.membership.max()) + 1 if c.n_points else 1
            source = "membership"
        entry = channel_storage(c.nnz, c.n_points, k, c.mode_sizes)
        entry["dictionary_source"] = source
        per[ch] = entry
    parts = None
    # A coded BTF the file format cannot hold (an evaluation baseline's identity
    # preprocessing) has no stored size: its report has no stored keys.
    if stored and (file_path is not None or coded.stats.transform == "log_yuv"):
        from .coded_file import coded_image

        parts = stored_bytes(file_path if file_path is not None else coded_image(coded))
    stats_bytes = 4 * (int(coded.stats.mean.size) + int(coded.stats.std.size))
    hl = (coded.highlights.nbytes(coded.patch, len(coded.lights), len(coded.views))
          if coded.highlights is not None else 0)  # fmt: skip
    out = _combine(
        per, coded.height, coded.width, len(coded.lights), len(coded.views), stats_bytes, parts,
        hl,
    )
    out["file_bytes"] = Path(file_path).stat().st_size if file_path is not None else None
    out["bytes_model_file"] = _model_file_bytes(m, coded.model_hash)
    return out


def _model_file_bytes(model: Model | None, content_hash: str) -> int | None:
    """Size of the model's file (its own, or the bundled one of that hash); None if unknown."""
    from .bundled import bundled_models, bundled_name

    path = model.file if model is not None else None
    name = bundled_name(content_hash)
    if not path and name is not None:
        path = str(bundled_models()[name].path)
    return Path(path).stat().st_size if path and Path(path).exists() else None


def storage_summary(report: dict[str, Any]) -> dict[str, Any]:
    """The figures of a :func:`storage_report` that a person reads, grouped by accounting:
    ``stored`` (what the file holds, part by part, summing to its size, and raw / that),
    ``table4`` (the paper's bytes and ratios), ``shared`` (the model, not in any
    per-material figure) and ``stored_codes_vs_table4``."""
    out: dict[str, Any] = {"bytes_raw_fp16": report["bytes_raw"]}
    if "bytes_stored" in report:
        out["stored"] = {
            "bytes_codes": report["bytes_stored_codes"],
            "bytes_statistics": report["bytes_stored_stats"],
            "bytes_directions": report["bytes_stored_directions"],
            "bytes_header": report["bytes_stored_header"],
            "bytes_file": report["bytes_stored"],
            "ratio_per_material": report["compression_ratio_per_material"],
        }
    out["table4"] = {
        "bytes_coefficients": report["bytes_coefficients"],
        "bytes_membership_counts": report["bytes_membership_counts"],
        "bytes_material": report["bytes_table4_material"],
        "ratio_per_material": report["compression_ratio_table4_material"],
        "bytes_with_dictionaries": report["bytes_total"],
        "ratio_with_dictionaries": report["compression_ratio"],
    }
    out["shared"] = {
        "bytes_dictionaries_table4": report["bytes_dictionaries"],
        "bytes_model_file": report.get("bytes_model_file"),
    }
    if "stored_codes_vs_table4" in report:
        out["stored_codes_vs_table4"] = report["stored_codes_vs_table4"]
    return out
