"""The two objects a user keeps: a trained :class:`Model` and a :class:`CodedBTF` per material.

* A **model** holds one dictionary ensemble per coded channel ("Y", "U", "V"; or "YUV" for the
  5D variant with colour as a mode), the data-point geometry (patch size, direction tables) and
  the training parameters and provenance. It is trained once and serves every BTF (paper
  criterion d); coded files name it by :attr:`Model.content_hash`.
* A **coded BTF** holds per channel the sparse codes
  (:class:`~sparsebtf.learning.coding.SparseCodes`),
  the standardisation statistics of the material, its size and directions, the coding
  parameters, and the hash of its model.

Files: :mod:`sparsebtf.storage` (HDF5, schema in ``docs/format.md``).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .data.directions import DirectionSet
from .errors import BTFInputError, ModelMismatchError
from .learning.coding import SparseCodes
from .preprocessing import Standardization

__all__ = ["CHANNELS", "CodedBTF", "Model", "dictionaries_hash"]

#: Channels of the default 4D pipeline, in order. The 5D variant uses one channel "YUV".
CHANNELS = ("Y", "U", "V")


def dictionaries_hash(ensembles: dict[str, list[np.ndarray]]) -> str:
    """SHA-256 over channel names, mode sizes and float64 dictionary bytes (content address)."""
    h = hashlib.sha256()
    for ch in sorted(ensembles):
        h.update(ch.encode())
        for d in ensembles[ch]:
            arr = np.ascontiguousarray(d, dtype="<f8")
            h.update(str(arr.shape).encode())
            h.update(arr.tobytes())
    return h.hexdigest()


@dataclass(eq=False)
class Model:
    """A trained SparseBTF model: one ensemble of K orthonormal dictionaries per channel.

    Attributes
    ----------
    dictionaries : channel → list over modes of (K, m_n, m_n) float64 orthonormal matrices.
        4D: modes (row-in-patch, col-in-patch, light, view); 5D adds colour (size 3) last.
    patch : spatial patch size p.
    lights, views : direction tables the ensembles were trained for.
    params : training parameters (tau_train per channel, n_dictionaries, sample, seed, ...).
    provenance : where it came from (materials, library version, time, release import ...).
    training : per channel diagnostics (objective history, membership histogram, seconds).
    """

    dictionaries: dict[str, list[np.ndarray]]
    patch: int
    lights: DirectionSet
    views: DirectionSet
    params: dict[str, Any] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)
    training: dict[str, dict[str, Any]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.dictionaries:
            raise BTFInputError("a model needs at least one channel")
        for ch, mats in self.dictionaries.items():
            ks = {m.shape[0] for m in mats}
            if len(ks) != 1:
                raise BTFInputError(f"channel {ch}: modes disagree on the number of dictionaries")
            for n, m in enumerate(mats):
                if m.ndim != 3 or m.shape[1] != m.shape[2]:
                    raise BTFInputError(
                        f"channel {ch}, mode {n + 1}: expected (K, m, m), got {m.shape}"
                    )
        self._hash: str | None = None

    @property
    def channels(self) -> tuple[str, ...]:
        return tuple(ch for ch in (*CHANNELS, "YUV") if ch in self.dictionaries)

    @property
    def mode_sizes(self) -> tuple[int, ...]:
        """Data-point shape of the first channel, e.g. (10, 10, 151, 151)."""
        first = self.dictionaries[self.channels[0]]
        return tuple(int(m.shape[1]) for m in first)

    def n_dictionaries(self, channel: str) -> int:
        return int(self.dictionaries[channel][0].shape[0])

    def dictionary_entries(self, channel: str) -> int:
        """Number of stored dictionary values of a channel: K·Σ m_n² (Table 4's dictSize)."""
        return int(sum(m.size for m in self.dictionaries[channel]))

    @property
    def content_hash(self) -> str:
        if self._hash is None:
            self._hash = dictionaries_hash(self.dictionaries)
        return self._hash

    def matrices(self, channel: str, k: int, dtype: type = np.float64) -> list[np.ndarray]:
        """The N mode matrices of dictionary ``k`` of ``channel``."""
        return [np.asarray(m[k], dtype=dtype) for m in self.dictionaries[channel]]


@dataclass(eq=False)
class CodedBTF:
    """One BTF as sparse coefficients on a :class:`Model`.

    Attributes
    ----------
    codes : channel → SparseCodes over the P data points (release numbering).
    stats : per-angular-image standardisation of this material.
    height, width, patch : spatial size and patch size (H, W multiples of p).
    lights, views : direction tables.
    model_hash : :attr:`Model.content_hash` of the model the codes refer to.
    params : coding parameters (tau per channel, eps, std_mode, ...).
    name : material label.
    attrs : provenance of the source BTF.
    model : the model itself once attached (needed to decode).
    """

    codes: dict[str, SparseCodes]
    stats: Standardization
    height: int
    width: int
    patch: int
    lights: DirectionSet
    views: DirectionSet
    model_hash: str
    params: dict[str, Any] = field(default_factory=dict)
    name: str = "btf"
    attrs: dict[str, Any] = field(default_factory=dict)
    model: Model | None = None

    @property
    def channels(self) -> tuple[str, ...]:
        return tuple(ch for ch in (*CHANNELS, "YUV") if ch in self.codes)

    @property
    def n_points(self) -> int:
        return (self.height // self.patch) * (self.width // self.patch)

    def nnz(self) -> dict[str, int]:
        return {ch: self.codes[ch].nnz for ch in self.channels}

    def attach(self, model: Model) -> CodedBTF:
        """Attach the model these codes were made with; refuses any other model."""
        if model.content_hash != self.model_hash:
            raise ModelMismatchError(
                f"{self.name}: coded with model {self.model_hash[:12]}…, but the given model is "
                f"{model.content_hash[:12]}…"
            )
        self.model = model
        return self

    def require_model(self) -> Model:
        if self.model is None:
            raise ModelMismatchError(
                f"{self.name}: no model attached; load the coded file with its model file"
            )
        return self.model
