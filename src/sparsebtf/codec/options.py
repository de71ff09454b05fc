"""The options of encoding and training, each in one object with one table of constraints.

:class:`EncodeOptions` is how every encoder codes (:func:`sparsebtf.encode`,
:func:`~sparsebtf.codec.encode`, :func:`~sparsebtf.codec.encode_to_size`,
:func:`~sparsebtf.codec.encode_many` …) and :class:`TrainOptions` how
:func:`~sparsebtf.codec.train` learns; where the work runs is an
:class:`~sparsebtf.execution.Execution`. Each is checked when it is made
(:mod:`sparsebtf.constraints`); the command line builds the same objects from its flags, so
a bad value is refused with the same line (naming the flag). The functions also take the
options as keywords, which build the object (:func:`encode_settings`, :func:`train_settings`)::

    sb.encode(btf, model, target="50x", options=EncodeOptions(candidates=None), workers=4)
"""

from __future__ import annotations

import numbers
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

from ..constraints import Interval, Options, Rule, StrOptions
from ..errors import BTFInputError, OptionError
from ..execution import Execution
from ..learning.codes import DTYPES, RELEASE_EPS, RELEASE_TAU_TRAIN
from ..learning.coding import DEFAULT_CANDIDATES
from ..learning.ensemble import FULL_PASS_EVERY, INITS
from ..learning.objective import OBJECTIVES
from ..learning.partitions import PARTITION_POINTS
from ..model import CHANNELS
from ..points.grid import MAX_PATCH, RELEASE_PATCH, parse_patches
from ..points.preprocessing import (
    LOG_OFFSET_RULE,
    STD_MODES,
    TRANSFORMS,
    LogOffset,
    StdMode,
    Transform,
)
from .levels import TauTrainSpec, parse_tau_train

__all__ = [
    "WEIGHTINGS",
    "EncodeOptions",
    "TrainOptions",
    "encode_settings",
    "train_settings",
]

#: Error weightings of the rate control (:func:`~sparsebtf.codec.encode_rate_levels`).
WEIGHTINGS = ("rgb", "log", "uniform")

#: Options that apply to a fixed τ only, to rate control only (a size, a ratio, byte
#: targets) and to many BTFs only (:func:`~sparsebtf.codec.encode_many`): as keywords
#: elsewhere they are refused in one line (an options object is taken as it is).
TAU_ONLY = ("eps", "allow_below_training", "highlights")
RATE_ONLY = ("weighting", "split", "candidate_factor", "budget", "per_material")
MANY_ONLY = ("crop", "checkpoint_dir")


def _crop(value: Any) -> bool:
    return (isinstance(value, tuple) and len(value) == 2
            and all(isinstance(s, slice) for s in value))  # fmt: skip


def _split(value: Any) -> bool:
    return (isinstance(value, Sequence) and not isinstance(value, str) and len(value) > 0
            and all(isinstance(x, numbers.Real) and x > 0 for x in value))  # fmt: skip


def _tau_train(value: Any) -> bool:
    """One training τ_l, several (``"64,8,8/256,32,32"``) or ``"learn"``
    (:func:`~.levels.parse_tau_train`), for Y, U, V or the colour mode's one channel."""
    try:
        parse_tau_train(value, CHANNELS)
    except BTFInputError as e:
        try:
            parse_tau_train(value, ("YUV",))
        except BTFInputError:
            raise e from None
    return True


def _patches(value: Any) -> bool:
    """One patch size, or several that nest (``(20, 10, 5)``, ``"20,10,5"``: one ensemble
    per size, for adaptive patch sizes; :func:`~sparsebtf.points.grid.parse_patches`)."""
    parse_patches(value)
    return True


#: Shared entries: the same rule wherever the option is taken.
CANDIDATES = [Interval(int, 1, None, unit="(dictionaries per data point)"), None]
BATCH = [Interval(int, 1, 4096, unit="data points per batch")]
DTYPE = [StrOptions(DTYPES, what="dtype")]
CROP = [Rule(_crop, "(rows, columns) slices"), None]
FOLDER = [str, os.PathLike, None]
PROGRESS = [bool, None]


@dataclass(frozen=True, kw_only=True)
class EncodeOptions(Options):
    """How BTFs are coded (paper §3.3 and beyond); every encoder takes one (``options=``).

    * ``eps`` — fixed τ: a point stops taking coefficients once its mean squared residual
      (standardised log-YUV; under a linear or display ``objective``, that error) is below it.
    * ``candidates`` — dictionaries projected exactly per point and channel after the
      screening (:func:`~sparsebtf.learning.coding.screen_dictionaries`); None: every one,
      the paper's exhaustive rule.
    * ``objective`` — the error the codes minimise: "log" (the paper's), "linear" (linear
      RGB) or "display" (:mod:`sparsebtf.learning.objective`).
    * ``allow_below_training`` — accept τ_t < τ_l (the paper requires τ_t >= τ_l).
    * rate control: ``weighting`` (:data:`WEIGHTINGS`), ``split`` (the target over Y, U, V;
      default the release's 885:64:64) and ``candidate_factor`` (candidates per point kept,
      × its reference count).
    * ``std_mode`` (default: the model's), ``log_offset`` (the rule of ln(x + offset): "auto",
      "release" or a number), ``batch_size`` (points read at a time), ``dtype``.
    * ``crop`` (rows, columns) of every input, ``checkpoint_dir`` (resume from the point
      ranges saved there), ``progress`` (bars; None: on a terminal).
    * ``adaptive_patches`` — adaptive patch sizes on a model of several
      (:mod:`sparsebtf.codec.adaptive`): :func:`sparsebtf.encode` codes each block of the
      largest size as one point or smaller ones, by rate and distortion; the fixed-size
      encoders refuse it.
    * ``highlights`` — fixed τ: each level's τ sets its bytes, spent on the codes at that τ
      or fewer coefficients plus linear-RGB corrections at the nodes where they remove
      the most error and a glossy lobe per texel where it pays (:mod:`sparsebtf.codec.
      highlights`; for glossy materials). True or "lobes": both; "entries": the corrections
      alone (no lobe fit, which costs seconds per data point).
    """

    eps: float = RELEASE_EPS
    candidates: int | None = DEFAULT_CANDIDATES
    objective: str = "log"
    allow_below_training: bool = False
    weighting: str = "rgb"
    split: Sequence[float] | None = None
    candidate_factor: float = 4.0
    std_mode: StdMode | None = None
    log_offset: LogOffset = "auto"
    batch_size: int = 4
    dtype: str = "float32"
    crop: tuple[slice, slice] | None = None
    checkpoint_dir: str | os.PathLike[str] | None = None
    progress: bool | None = None
    adaptive_patches: bool = False
    highlights: bool | str = False

    constraints: ClassVar[dict[str, list[Any]]] = {
        "adaptive_patches": [bool],
        "highlights": [bool, StrOptions(("lobes", "entries"), what="highlight store")],
        "eps": [Interval(float, 0, None, unit="(residual mean squared error, standardised)")],
        "candidates": CANDIDATES,
        "objective": [StrOptions(OBJECTIVES, what="coding objective")],
        "allow_below_training": [bool],
        "weighting": [StrOptions(WEIGHTINGS, what="weighting")],
        "split": [Rule(_split, "positive numbers, one per channel (Y, U, V)"), None],
        "candidate_factor": [Interval(float, 1, None, unit="(candidates per reference count)")],
        "std_mode": [StrOptions(STD_MODES, what="standardisation mode"), None],
        "log_offset": LOG_OFFSET_RULE,
        "batch_size": BATCH,
        "dtype": DTYPE,
        "crop": CROP,
        "checkpoint_dir": FOLDER,
        "progress": PROGRESS,
    }


@dataclass(frozen=True, kw_only=True)
class TrainOptions(Options):
    """How a model is learned (paper §3.2); :func:`~sparsebtf.codec.train` takes one.

    * ``n_dictionaries`` K per ensemble, ``tau_train`` τ_l per channel (default the paper's
      256,32,32; several levels ``"64,8,8/256,32,32"``, K split evenly over them; or
      ``"learn"``: each dictionary's τ_l chosen on a validation split; each level once, and
      K a multiple of their number), ``tau_validation`` (with ``"learn"`` only: the coding
      τ_t the validation error is read at), ``patch`` p (or several that nest, largest first,
      ``(20, 10, 5)``: one ensemble per size, trained one after the other on the same
      materials, for adaptive patch sizes),
      ``sample`` (the fraction of each BTF's points; paper: 10%).
    * ``max_iter``, ``tol`` (stop below this relative decrease of the objective), ``init``
      ("points", "random" or "preclustered"), ``seed``.
    * ``candidates`` / ``full_pass_every``: the coding passes between full ones
      (:class:`~sparsebtf.learning.ensemble.DictionaryEnsemble`; None: all K when a full
      pass is cheap, else 1); the final memberships always come from a full pass.
    * ``std_mode``, ``colour_mode`` (one 5D ensemble, the paper's Table 6), ``preprocessing``
      ("log_yuv" or "identity": raw linear RGB, the [MHU19] baseline), ``log_offset`` (the rule
      of each BTF's offset in ln(x + offset)).
    * ``batch_size``, ``partition_size`` (points per task), ``dtype``, ``stage`` /
      ``stage_dir`` (preprocess the sampled points once into a file; None: when they fit),
      ``checkpoint_dir`` (resume each channel from its last iteration), ``crop``, ``progress``.
    """

    n_dictionaries: int = 8
    tau_train: TauTrainSpec = RELEASE_TAU_TRAIN
    tau_validation: TauTrainSpec | None = None
    patch: int | Sequence[int] | str = RELEASE_PATCH
    sample: float = 0.1
    max_iter: int = 10
    tol: float = 1e-4
    std_mode: StdMode = "shared"
    colour_mode: bool = False
    init: str = "points"
    candidates: int | None = None
    full_pass_every: int = FULL_PASS_EVERY
    batch_size: int = 4
    partition_size: int = PARTITION_POINTS
    dtype: str = "float32"
    seed: int = 0
    checkpoint_dir: str | os.PathLike[str] | None = None
    stage: bool | None = None
    stage_dir: str | os.PathLike[str] | None = None
    progress: bool | None = None
    preprocessing: Transform = "log_yuv"
    log_offset: LogOffset = "auto"
    crop: tuple[slice, slice] | None = None

    constraints: ClassVar[dict[str, list[Any]]] = {
        "n_dictionaries": [Interval(int, 1, 255, unit="dictionaries per ensemble")],
        "tau_train": [Rule(_tau_train, "a tau: an integer >= 1, or one per channel "
                                        "('Y,U,V'); several as 'Y,U,V/Y,U,V'; or 'learn'")],
        "tau_validation": [Rule(_tau_train, "coding taus: 'Y,U,V' or several as "
                                            "'Y,U,V/Y,U,V'"), None],
        "patch": [Rule(_patches, f"a patch size in texels in [1, {MAX_PATCH}], or several "
                             "that nest (each divides the next larger) such as 20,10,5")],
        "sample": [Interval(float, 0, 1, closed="right",
                            unit="(fraction of each BTF's data points)")],
        "max_iter": [Interval(int, 1, 10**6, unit="iterations")],
        "tol": [Interval(float, 0, None, unit="(relative objective decrease)")],
        "std_mode": [StrOptions(STD_MODES, what="standardisation mode")],
        "colour_mode": [bool],
        "init": [StrOptions(INITS, what="initialisation")],
        "candidates": CANDIDATES,
        "full_pass_every": [Interval(int, 0, 10**6, unit="iterations")],
        "batch_size": BATCH,
        "partition_size": [Interval(int, 1, None, unit="points per partition")],
        "dtype": DTYPE,
        "seed": [Interval(int, 0, 2**32 - 1)],
        "checkpoint_dir": FOLDER,
        "stage": [bool, None],
        "stage_dir": FOLDER,
        "progress": PROGRESS,
        "preprocessing": [StrOptions(TRANSFORMS, what="preprocessing")],
        "log_offset": LOG_OFFSET_RULE,
        "crop": CROP,
    }

    def check(self) -> None:
        """The rules between options, the same for the library and the command line (which
        names the flags): ``tau_validation`` only with a learned ``tau_train``, and K =
        ``n_dictionaries`` split evenly over several training levels."""
        channels = ("YUV",) if self.colour_mode else CHANNELS
        try:
            levels, learn = parse_tau_train(self.tau_train, channels)
        except BTFInputError:  # the other channels' spelling: train() names the mismatch
            return
        if self.tau_validation is not None and not learn:
            given = repr(self.tau_train).replace("{", "{{").replace("}", "}}")
            raise OptionError("tau_validation", ": has no effect unless {tau_train} is 'learn' "
                              f"(the coding tau a learned tau_l is chosen at); {{tau_train}} is "
                              f"{given}", mentions=("tau_train",))  # fmt: skip
        from ..learning.tau_levels import VALIDATION, check_levels

        for per_channel in levels.values():
            try:
                check_levels(per_channel, self.n_dictionaries, learn, VALIDATION)
            except BTFInputError as e:
                text = str(e).replace("{", "{{").replace("}", "}}")
                raise OptionError("n_dictionaries", f": {text}") from None


def encode_settings(
    options: EncodeOptions | None, execution: Execution | None, keywords: dict[str, Any], *,
    kind: str, many: bool,
) -> tuple[EncodeOptions, Execution]:  # fmt: skip
    """The options and the place of one encode: ``options`` and ``execution`` (defaults if
    None) with ``keywords`` in place. A keyword that does not apply to this encode — ``kind``
    "tau" (fixed τ) or a rate target ("size", "ratio"), one BTF or ``many`` — is one line."""
    for key in keywords:
        if key in MANY_ONLY and not many:
            raise BTFInputError(f"option {key!r} does not apply to one BTF (encode_many and a "
                                "list of BTFs take it; or set it in EncodeOptions)")  # fmt: skip
        if (key in TAU_ONLY and kind != "tau") or (key in RATE_ONLY and kind == "tau"):
            other = RATE_ONLY if kind == "tau" else TAU_ONLY
            ok = [n for n in (*EncodeOptions.names(), *Execution.names())
                  if n not in other and (many or n not in MANY_ONLY)]  # fmt: skip
            raise BTFInputError(f"option {key!r} does not apply to a {kind} target; options "
                                f"there: {', '.join(ok)}")  # fmt: skip
    where, rest = Execution.take(execution, keywords)
    return EncodeOptions.build(options, **rest), where


def train_settings(options: TrainOptions | None, execution: Execution | None,
                   keywords: dict[str, Any]) -> tuple[TrainOptions, Execution]:  # fmt: skip
    """The options and the place of one training, as :func:`encode_settings`."""
    where, rest = Execution.take(execution, keywords)
    return TrainOptions.build(options, **rest), where
