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
import math
import numbers
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from .data.directions import DirectionSet
from .errors import BTFInputError, ModelMismatchError, SparseBTFError
from .learning.coding import SparseCodes
from .learning.highlights import Highlights
from .points.preprocessing import Standardization, StdMode, Transform

if TYPE_CHECKING:
    from .data.btf import BTF

__all__ = [
    "CHANNELS",
    "DEFAULT_STD_MODE",
    "DEFAULT_TRANSFORM",
    "MAX_TAU",
    "CodedBTF",
    "Model",
    "TauSpec",
    "dictionaries_hash",
    "model_text",
    "parse_tau",
]

#: The largest τ any reader accepts: per-point counts are stored as uint32. Where a model is
#: known, encoding and training refuse more than a data point's coefficients.
MAX_TAU = 2**32 - 1
#: Channels of the default 4D pipeline, in order. The 5D variant uses one channel "YUV".
CHANNELS = ("Y", "U", "V")
#: Defaults of model parameters that older model files (and the release import) leave out.
DEFAULT_STD_MODE: StdMode = "shared"
DEFAULT_TRANSFORM: Transform = "log_yuv"

#: What a τ can be given as; see :func:`parse_tau`.
TauSpec = None | int | float | str | Sequence[int] | Mapping[str, int]
_ALL = ("all", "full", "none")


def _tau_error(tau: object, why: str, fractions: bool = True) -> BTFInputError:
    frac = "; or a fraction in (0, 1) of the coded tau such as 0.25" if fractions else ""
    return BTFInputError(
        f"tau {tau!r}: {why} (give integers: one for all channels or 'Y,U,V' such as "
        f"'885,64,64'{frac})"
    )


def parse_tau(
    tau: TauSpec,
    channels: Sequence[str] = CHANNELS,
    *,
    full: Mapping[str, int] | None = None,
    nominal: Mapping[str, int] | None = None,
) -> dict[str, int]:
    """τ per channel: the one reader of the τ syntax (CLI, Python API, plugin properties).

    Accepted: an integer (every channel); a sequence of integers, one per channel (or one);
    a ``{channel: τ}`` mapping; a string ``"885,64,64"``, ``"64"`` or ``"0.25"``; a fraction in
    (0, 1) of the coded τ (``nominal``, else ``full``), rounded up; ``None`` or ``"all"`` for
    every stored coefficient (``full``). Encoding passes only ``nominal`` (the release's
    885,64,64, :data:`sparsebtf.learning.codes.RELEASE_TAU`): a fraction is of that, and a
    count is needed. Where neither is given, only explicit counts are accepted. Every τ is an
    integer >= 1.
    """
    given = tau
    frac = full is not None or nominal is not None
    if isinstance(tau, str):
        text = tau.strip()
        if text.lower() in _ALL:
            tau = None
        elif "," in text:
            tau = [p.strip() for p in text.split(",")]
        else:
            try:
                tau = int(text)
            except ValueError:
                try:
                    tau = float(text)
                except ValueError:
                    raise _tau_error(given, "not a number", frac) from None
    if tau is None:
        if full is None:
            raise _tau_error(given, "a count is needed here", frac)
        return {ch: int(full[ch]) for ch in channels}
    if isinstance(tau, bool):
        raise _tau_error(given, "not a number", frac)
    if isinstance(tau, numbers.Real) and not isinstance(tau, numbers.Integral):
        f = float(tau)
        if math.isfinite(f) and f.is_integer():
            tau = int(f)
        else:
            if full is None and nominal is None:
                raise _tau_error(given, "a fraction needs a coded tau to be a fraction of", frac)
            if not 0 < f < 1:
                raise _tau_error(given, "a fractional tau must be in (0, 1)", frac)
            base = {**(full or {}), **(nominal or {})}
            return {ch: max(1, math.ceil(f * int(base[ch]))) for ch in channels}
    if isinstance(tau, Mapping):
        missing = [ch for ch in channels if ch not in tau]
        if missing:
            raise _tau_error(given, f"no value for channel(s) {missing}", frac)
        values: list[Any] = [tau[ch] for ch in channels]
    elif isinstance(tau, numbers.Integral):
        values = [tau]
    else:
        values = list(tau)
    counts = []
    for v in values:
        if isinstance(v, numbers.Integral) and not isinstance(v, bool):
            counts.append(int(v))  # exactly, however large (float() would round it)
            continue
        if isinstance(v, str) and v.strip().isdigit():
            counts.append(int(v))
            continue
        try:
            f = float(v)
        except (TypeError, ValueError):
            raise _tau_error(given, f"{v!r} is not an integer", frac) from None
        if not (math.isfinite(f) and f.is_integer()):
            raise _tau_error(given, f"{v!r} is not an integer", frac)
        counts.append(int(f))
    if len(counts) == 1:
        counts = counts * len(channels)
    if len(counts) != len(channels):
        raise _tau_error(
            given, f"needs one value per channel {tuple(channels)}, got {len(counts)}", frac
        )
    if any(c < 1 for c in counts):
        raise _tau_error(given, "every tau must be >= 1", frac)
    if any(c > MAX_TAU for c in counts):
        raise _tau_error(given, f"every tau must be <= {MAX_TAU} (counts are stored as uint32)",
                         frac)  # fmt: skip
    return dict(zip(channels, counts, strict=True))


#: Functions that name a model from its content hash, or return None: the registry of bundled
#: models adds its own when it is imported (:mod:`sparsebtf.storage.bundled`), so this module
#: does not import the storage layer above it.
MODEL_NAMERS: list[Callable[[str], str | None]] = []


def model_text(content_hash: str, file: str | None = None) -> str:
    """How a message names a model: ``model 819ce9fcd073… (bundled 'release')``, or with its
    file (``(file my-model.h5)``), so a user sees which model, not only a hash."""
    name = None
    for namer in MODEL_NAMERS:
        try:
            name = namer(content_hash)
        except SparseBTFError:  # a damaged installation must not hide the real error
            name = None
        if name:
            break
    where = f"bundled '{name}'" if name else f"file {file}" if file else "not a bundled model"
    return f"model {content_hash[:12]}… ({where})"


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
    patches : the ensembles at other patch sizes (adaptive patch sizes, :mod:`sparsebtf.
        patch_tree`): size → channel → modes, the same channels, K and direction tables;
        every size nests with ``patch`` (:func:`~sparsebtf.points.grid.check_nested`).
        Empty for a model of one size (every file before them; the bundled model).
    file : the model file it was last saved to or loaded from (None for a model only in
        memory); not part of its content. Saving a coded BTF records it.
    """

    dictionaries: dict[str, list[np.ndarray]]
    patch: int
    lights: DirectionSet
    views: DirectionSet
    params: dict[str, Any] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)
    training: dict[str, dict[str, Any]] = field(default_factory=dict)
    patches: dict[int, dict[str, list[np.ndarray]]] = field(default_factory=dict)

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
        if self.patches:
            self._check_patches()
        self._hash: str | None = None
        self.file: str | None = None

    def _check_patches(self) -> None:
        """Every other size: nested with ``patch``, the same channels, K and angular modes."""
        from .points.grid import check_nested

        sizes = [self.patch, *self.patches]
        check_nested(sizes, f"model patch sizes {sizes}")
        for p, ens in self.patches.items():
            if set(ens) != set(self.dictionaries):
                raise BTFInputError(f"patch size {p}: channels {sorted(ens)} differ from the "
                                    f"model's {sorted(self.dictionaries)}")  # fmt: skip
            for ch, mats in ens.items():
                main = self.dictionaries[ch]
                want = (p, p, *(int(m.shape[1]) for m in main[2:]))
                got = tuple(int(m.shape[1]) for m in mats)
                ks = {int(m.shape[0]) for m in mats}
                if got != want or ks != {int(main[0].shape[0])} or any(
                        m.ndim != 3 or m.shape[1] != m.shape[2] for m in mats):
                    raise BTFInputError(
                        f"patch size {p}, channel {ch}: expected {len(want)} modes of sizes "
                        f"{want} with K = {int(main[0].shape[0])}, got {got} with K {sorted(ks)}"
                    )

    @property
    def patch_sizes(self) -> tuple[int, ...]:
        """Every patch size the model has an ensemble for, largest first (one for most)."""
        return tuple(sorted({int(self.patch), *map(int, self.patches)}, reverse=True))

    def for_patch(self, patch: int) -> Model:
        """The model of one of its patch sizes: itself for ``patch``, else a model of the
        ensembles at that size that keeps this model's content hash and file (codes made on
        it name this model, the file that holds every size)."""
        if patch == self.patch:
            return self
        if patch not in self.patches:
            raise ModelMismatchError(f"{model_text(self.content_hash, self.file)} has no "
                                     f"ensemble for {patch}x{patch} patches (its sizes: "
                                     f"{', '.join(map(str, self.patch_sizes))})")  # fmt: skip
        one = Model(self.patches[patch], patch, self.lights, self.views, self.params,
                    self.provenance, self.training)  # fmt: skip
        one._hash = self.content_hash
        one.file = self.file
        return one

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
            if self.patches:  # several sizes: every ensemble, by size (one size: unchanged)
                h = hashlib.sha256(f"patches:{self.patch}:{self._hash}".encode())
                for p in sorted(self.patches, reverse=True):
                    h.update(f"|{p}:{dictionaries_hash(self.patches[p])}".encode())
                self._hash = h.hexdigest()
        return self._hash

    def matrices(self, channel: str, k: int, dtype: type = np.float64) -> list[np.ndarray]:
        """The N mode matrices of dictionary ``k`` of ``channel``."""
        return [np.asarray(m[k], dtype=dtype) for m in self.dictionaries[channel]]

    # -- training parameters, with the defaults of files that leave them out --------------
    @property
    def std_mode(self) -> StdMode:
        """Standardisation the model was trained with ("shared", the release's, by default)."""
        return self.params.get("std_mode", DEFAULT_STD_MODE)

    @property
    def transform(self) -> Transform:
        """Preprocessing of its data points: "log_yuv" (§3.1) or "identity" ([MHU19])."""
        return self.params.get("preprocessing", DEFAULT_TRANSFORM)

    @property
    def tau_train(self) -> dict[str, int]:
        """Training sparsity τ_l per channel (empty when unknown, e.g. the release import)."""
        return {ch: int(v) for ch, v in (self.params.get("tau_train") or {}).items()}

    def dictionary_taus(self, channel: str) -> list[int]:
        """The training τ_l of each of ``channel``'s K dictionaries: ``tau_dictionaries`` of a
        model trained at several levels, else K times the channel's one ``tau_train`` (a
        model of one level, every older file); empty when unknown (the release import)."""
        per = (self.params.get("tau_dictionaries") or {}).get(channel)
        if per is not None:
            return [int(t) for t in per]
        t = self.tau_train.get(channel)
        return [] if t is None else [t] * self.n_dictionaries(channel)

    def check_directions(self, btf: BTF) -> None:
        """Codes only mean something on the direction tables the model was trained for."""
        if not (btf.lights.equals(self.lights) and btf.views.equals(self.views)):
            raise ModelMismatchError(
                f"{btf.label}: {len(btf.lights)} lights x {len(btf.views)} views do not match the "
                f"model's {len(self.lights)} x {len(self.views)} direction tables"
            )


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
    #: The coded file it was read from (:func:`sparsebtf.storage.load_coded`), or None.
    source: str | None = None
    #: Exact corrections at a few nodes (:mod:`sparsebtf.learning.highlights`), added by
    #: every decoder after the sparse code's value; None: no highlight store.
    highlights: Highlights | None = None

    @property
    def label(self) -> str:
        """How messages name these codes: their file when they have one, else the name."""
        return self.source or self.name

    @property
    def channels(self) -> tuple[str, ...]:
        return tuple(ch for ch in (*CHANNELS, "YUV") if ch in self.codes)

    @property
    def highlight_store(self) -> Highlights | None:
        """:attr:`highlights` when it holds entries or lobes, else None: an empty store
        changes no decoded value, so every reader and writer treats it as none."""
        h = self.highlights
        return h if h is not None and not h.empty_store else None

    @property
    def n_points(self) -> int:
        return (self.height // self.patch) * (self.width // self.patch)

    def nnz(self) -> dict[str, int]:
        return {ch: self.codes[ch].nnz for ch in self.channels}

    @property
    def stored_tau(self) -> dict[str, int]:
        """The largest count of any point per channel: every stored coefficient."""
        return {ch: int(np.max(self.codes[ch].counts, initial=0)) for ch in self.channels}

    @property
    def coded_tau(self) -> dict[str, int]:
        """τ the material was coded at (``params["tau"]``; the stored counts when absent)."""
        coded = self.params.get("tau") or {}
        return {**self.stored_tau, **{ch: int(v) for ch, v in coded.items()}}

    @property
    def model_file(self) -> str | None:
        """Path of the model file recorded at encoding (``params["model_file"]``), if any."""
        return self.params.get("model_file") or None

    @property
    def dictionary_rule(self) -> tuple[str, int | None]:
        """How each point's dictionary was chosen: ("exhaustive", None), every dictionary
        projected (the paper's rule; also files written before the record), or ("screened",
        N), N candidates projected exactly after the screening (``params``
        ``dictionary_rule`` / ``dictionary_candidates``, docs/format.md)."""
        if self.params.get("dictionary_rule") == "screened":
            return "screened", int(self.params["dictionary_candidates"])
        return "exhaustive", None

    @property
    def objective(self) -> str:
        """The error the codes minimise (``params["objective"]``, :mod:`sparsebtf.learning.
        objective`): "log" (the paper's rule; also files written before the record),
        "linear" or "display"."""
        return str(self.params.get("objective") or "log")

    def dictionary_count(self, channel: str, model: Model | None = None) -> int | None:
        """K of a channel: from ``model`` or the attached one, else the coding parameters
        (``params["n_dictionaries"]``, an int or one per channel); None when unknown."""
        m = model or self.model
        if m is not None and channel in m.dictionaries:
            return m.n_dictionaries(channel)
        k = self.params.get("n_dictionaries")
        if isinstance(k, Mapping):
            k = k.get(channel)
        if isinstance(k, numbers.Integral) and not isinstance(k, bool) and k > 0:
            return int(k)
        return None

    def resolve_tau(self, tau: TauSpec) -> dict[str, int]:
        """τ' per channel of this material (:func:`parse_tau` with its counts: None = all
        stored coefficients, a fraction = of the coded τ)."""
        return parse_tau(tau, self.channels, full=self.stored_tau, nominal=self.coded_tau)

    def attach(self, model: Model) -> CodedBTF:
        """Attach the model these codes were made with; refuses any other model."""
        if model.content_hash != self.model_hash:
            raise ModelMismatchError(
                f"{self.label}: coded with {model_text(self.model_hash, self.model_file)}, but "
                f"the given model is {model_text(model.content_hash, model.file)}"
            )
        self.model = model
        return self

    def require_model(self) -> Model:
        if self.model is None:
            raise ModelMismatchError(
                f"{self.label}: no model attached; load the coded file with its model file"
            )
        return self.model
