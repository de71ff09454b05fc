"""Storage accounting as in the paper's Table 4 (the release's ``btf4Dcomp``).

Per channel the bytes are those of the Table 4 formula
(:func:`sparsebtf.learning.cost.channel_storage`: values, locations, dictionaries, membership
and counts). Raw size is H·W·L·V·3 values at 2 bytes (binary16). The compression ratio is
raw / (coefficients + dictionaries + membership/counts); the standardisation statistics are
reported apart (``bytes_stats``) and not in the ratio, as in the paper. For UBO2014 at
τ = (885, 64, 64), K = 8 and 1600 points per channel this gives 10,312,096 B ≈ 9.83 MiB and a
ratio of ≈ 2122.6 (Table 4's 2122). The dictionaries are counted once per channel although the
model is shared by every material; ``compression_ratio_per_material`` leaves them out.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ..errors import BTFInputError, ModelMismatchError
from ..learning.cost import channel_storage, raw_bytes
from ..model import CHANNELS, CodedBTF, Model, model_text

__all__ = ["MIB", "paper_storage", "storage_report"]

#: Bytes per MiB (the paper reports sizes in MiB = 2^20 bytes).
MIB = float(1 << 20)


def _combine(
    per_channel: dict[str, dict[str, Any]],
    height: int, width: int, n_lights: int, n_views: int,
    bytes_stats: int, file_bytes: int | None,
) -> dict[str, Any]:
    raw_values = height * width * n_lights * n_views * 3
    coeff = sum(c["bytes_coefficients"] for c in per_channel.values())
    dicts = sum(c["bytes_dictionaries"] for c in per_channel.values())
    mz = sum(c["bytes_membership"] + c["bytes_counts"] for c in per_channel.values())
    total = coeff + dicts + mz
    raw = raw_bytes(raw_values)
    return {
        "bytes_raw": raw,
        "bytes_raw_float32": 4 * raw_values,
        "bytes_values": sum(c["bytes_values"] for c in per_channel.values()),
        "bytes_locations": sum(c["bytes_locations"] for c in per_channel.values()),
        "bytes_coefficients": coeff,
        "bytes_membership_counts": mz,
        "bytes_dictionaries": dicts,
        "bytes_stats": int(bytes_stats),
        # The release's <mat>_mean_std.bin: L·V means and L·V stds in float64.
        "bytes_stats_release": 2 * n_lights * n_views * 8,
        "bytes_total": total,
        "mib_total": total / MIB,
        "compression_ratio": raw / total if total else float("inf"),
        "compression_ratio_per_material": raw / (coeff + mz) if coeff + mz else float("inf"),
        "nnz": {ch: c["nnz"] for ch, c in per_channel.items()},
        "file_bytes": file_bytes,
        "channels": per_channel,
    }


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
    returned dict has the keys of :func:`storage_report` (``bytes_stats`` is our float32
    shared statistics, ``file_bytes`` is None). Example: ``paper_storage(400, 400, 151, 151,
    10, (885, 64, 64), 8)["bytes_total"] == 10_312_096`` (9.83 MiB, ratio ≈ 2122.6).
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
    return _combine(per, height, width, n_lights, n_views, 2 * 4 * n_lights * n_views, None)


def storage_report(
    coded: CodedBTF,
    model: Model | None = None,
    file_path: str | os.PathLike[str] | None = None,
) -> dict[str, Any]:
    """Storage of a coded BTF by the paper's Table 4 formula, plus the real file size.

    K (for the dictionary bytes) comes from ``model`` (or the model attached to ``coded``);
    without one, from ``coded.params["n_dictionaries"]`` (an int, or a dict per channel);
    failing that, from ``max(membership) + 1`` — a lower bound. Each channel's
    ``dictionary_source`` says which was used. Mode sizes are those of the codes.

    Keys: ``bytes_raw``, ``bytes_raw_float32``, ``bytes_values``, ``bytes_locations``,
    ``bytes_coefficients`` (values + locations), ``bytes_membership_counts``,
    ``bytes_dictionaries``, ``bytes_stats`` (our float32 mean and std), ``bytes_stats_release``
    (the release's float64 ``mean_std.bin``), ``bytes_total`` (coefficients + dictionaries +
    membership/counts; statistics excluded, as in Table 4), ``mib_total``, ``compression_ratio``
    (raw / total), ``compression_ratio_per_material`` (dictionaries excluded), ``nnz``
    (channel → count), ``file_bytes`` (size of ``file_path``, or None) and ``channels``
    (channel → per-channel details from :func:`channel_storage`).
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
    file_bytes = None
    if file_path is not None:
        file_bytes = Path(file_path).stat().st_size
    stats_bytes = 4 * (int(coded.stats.mean.size) + int(coded.stats.std.size))
    return _combine(
        per, coded.height, coded.width, len(coded.lights), len(coded.views), stats_bytes,
        file_bytes,
    )
