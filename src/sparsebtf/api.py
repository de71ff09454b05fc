"""The front functions of ``import sparsebtf as sb``: :func:`load_model`, :func:`encode` (one
function for τ, a target size or a ratio, one BTF or many) and :func:`decode`.

They choose and call the codec's encoders (:func:`~sparsebtf.codec.encode`,
:func:`~sparsebtf.codec.encode_to_size`, :func:`~sparsebtf.codec.encode_many`, with
:class:`~sparsebtf.codec.options.EncodeOptions` and :class:`~sparsebtf.execution.Execution`)
and the runtime's decoder (:func:`~sparsebtf.runtime.coded_btf_view`); every heavy import happens at
the first call, so ``import sparsebtf`` stays cheap.

>>> import sparsebtf as sb                                             # doctest: +SKIP
>>> coded = sb.encode(sb.open_btf("synth:stone:20:7"), target="50x")   # doctest: +SKIP
>>> sb.save_btf(coded, "stone.coded.h5")                               # doctest: +SKIP
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Iterator, Mapping, Sequence
from typing import TYPE_CHECKING, Any, overload

from .constraints import is_array, wrong_type
from .errors import BTFInputError

if TYPE_CHECKING:
    from .codec.options import EncodeOptions
    from .data.btf import BTF
    from .execution import Execution
    from .model import CodedBTF, Model
    from .runtime.dense import DecodedBTF

__all__ = ["Target", "decode", "encode", "load_model", "parse_target"]

#: What a model argument may be, in a refusal.
_MODEL = "a Model, a bundled model's name ('sparsebtf models' lists them), a model file's path"
#: What :func:`encode`'s ``target`` accepts (see :func:`parse_target`).
Target = None | str | Sequence[int] | Mapping[str, int]

#: Bytes per unit of a size target (decimal and binary prefixes; case does not matter).
_UNITS = {"b": 1, "kb": 10**3, "mb": 10**6, "gb": 10**9, "kib": 2**10, "mib": 2**20,
          "gib": 2**30}  # fmt: skip
_SIZE = re.compile(r"^\s*(\d+(?:\.\d*)?(?:e[+-]?\d+)?)\s*([kmg]i?b|b)\s*$", re.I)
_RATIO = re.compile(r"^\s*(\d+(?:\.\d*)?(?:e[+-]?\d+)?)\s*x\s*$", re.I)
_SPELLINGS = ('a tau such as (885, 64, 64), {"Y": 885, "U": 64, "V": 64}, "885,64,64" or '
              '"0.25" (a fraction of 885,64,64); a coded size such as "1.2MB", "300KiB" or '
              '"250000B"; or a compression ratio such as "50x"')


def load_model(spec: str | os.PathLike[str] = "release") -> Model:
    """The model ``spec`` names: a bundled model's name (``"release"``: the authors' Y/U/V
    ensembles, K = 8, 10×10 patches, the 151 UBO2014 directions; ``sparsebtf models`` lists
    them) or the path of a model file (``.h5`` from :func:`~sparsebtf.codec.train` saved by
    :func:`~sparsebtf.storage.save_model`, or from ``sparsebtf import-release``)."""
    from .storage.bundled import open_model

    if not isinstance(spec, str | os.PathLike):
        raise wrong_type("load_model", "spec", "a bundled model's name ('sparsebtf models' lists "
                         "them) or a model file's path", spec)  # fmt: skip
    return open_model(spec)


def parse_target(target: Target) -> tuple[str, Any]:
    """``target`` as ``("tau", τ)``, ``("bytes", n)`` or ``("ratio", r)``.

    * None → ``("tau", (885, 64, 64))``, the release's τ;
    * a tuple / list of integers, a ``{channel: τ}`` mapping, or a string in the τ syntax
      (``"885,64,64"``, ``"64"``, ``"0.25"``: :func:`~sparsebtf.model.parse_tau`) → τ;
    * a string with a byte unit, ``"1.2MB"``, ``"300KiB"``, ``"250000B"`` (k/M/G = 10³, 10⁶,
      10⁹; Ki/Mi/Gi = 2¹⁰, 2²⁰, 2³⁰) → a size in bytes, rounded down;
    * a string ending in ``x``, ``"50x"`` → a compression ratio.

    A bare number is refused: 64 could be a τ or a size; write ``(64,)``, ``"64B"`` or
    ``"64x"``. Every refusal is one :class:`~sparsebtf.errors.BTFInputError` line.
    """
    if target is None:
        from .learning.codes import RELEASE_TAU

        return "tau", RELEASE_TAU
    if isinstance(target, bool) or isinstance(target, int | float) or (
            hasattr(target, "dtype") and getattr(target, "ndim", 1) == 0):  # fmt: skip
        raise BTFInputError(f"target={target!r} is ambiguous (a tau or a size?): give "
                            f"({target!r},) or '{target}' for a tau, '{target}B' for a size "
                            f"in bytes or '{target}x' for a ratio")  # fmt: skip
    if isinstance(target, str):
        size, ratio = _SIZE.match(target), _RATIO.match(target)
        if size is not None:
            n = int(float(size.group(1)) * _UNITS[size.group(2).lower()])
            if n < 1:
                raise BTFInputError(f"target={target!r}: a size must be at least 1 byte")
            return "bytes", n
        if ratio is not None:
            r = float(ratio.group(1))
            if not r > 0:
                raise BTFInputError(f"target={target!r}: a ratio must be > 0")
            return "ratio", r
        if re.search(r"[a-z]", target, re.I):
            raise BTFInputError(f"target={target!r} is not a tau, size or ratio; give "
                                + _SPELLINGS)
    elif not isinstance(target, Sequence | Mapping):
        raise BTFInputError(f"target={target!r}: expected {_SPELLINGS}")
    return "tau", target


def _check_model(function: str, model: Any) -> None:
    from .model import Model

    if model is not None and not isinstance(model, Model | str | os.PathLike):
        raise wrong_type(function, "model", _MODEL + " or None", model)


def _model_of(model: Model | str | os.PathLike[str] | None, function: str = "encode") -> Model:
    from .model import Model

    _check_model(function, model)
    if model is None:
        return load_model("release")
    if isinstance(model, Model):
        return model
    return load_model(model)  # type: ignore[arg-type]


@overload
def encode(btf_or_btfs: BTF | str | os.PathLike[str], model: Model | str | os.PathLike[str] |
           None = None, *, target: Target = None, options: EncodeOptions | None = None,
           execution: Execution | None = None, **keywords: Any) -> CodedBTF: ...
@overload
def encode(btf_or_btfs: Iterable[BTF | str | os.PathLike[str]], model: Model | str |
           os.PathLike[str] | None = None, *, target: Target = None,
           options: EncodeOptions | None = None, execution: Execution | None = None,
           **keywords: Any) -> Iterator[CodedBTF]: ...
def encode(
    btf_or_btfs: Any,
    model: Model | str | os.PathLike[str] | None = None,
    *,
    target: Target = None,
    options: EncodeOptions | None = None,
    execution: Execution | None = None,
    **keywords: Any,
) -> CodedBTF | Iterator[CodedBTF]:
    """Sparse codes of one BTF, or of many, on ``model`` (paper §3.3; default: the bundled
    ``"release"`` model; a name or a model file is loaded with :func:`load_model`).

    ``btf_or_btfs``: a BTF, or a path / ``synth:`` spec (opened by
    :func:`~sparsebtf.open.open_btf`) → one :class:`~sparsebtf.model.CodedBTF`; a list or
    tuple (any iterable) of them → an iterator yielding one coded BTF per input, in order
    (:func:`~sparsebtf.codec.encode_many`; iterate to the end to release a cluster it started).

    ``target`` (:func:`parse_target`): a τ per data point and channel, ``(885, 64, 64)`` by
    default (:func:`~sparsebtf.codec.encode`: each point's sparsest code with mean squared
    residual below ``eps``, at most τ coefficients); or a coded size, ``"1.2MB"``, or a ratio,
    ``"50x"`` (rate control, :func:`~sparsebtf.codec.encode_to_size`). A size or a ratio means
    the coded file, as ``sparsebtf encode --target-ratio`` does: raw fp16 bytes / ratio
    (``budget="stored", per_material=True``); ``budget="paper", per_material=False`` count by
    Table 4 with the shared dictionaries.

    How it codes is ``options`` (:class:`~sparsebtf.codec.options.EncodeOptions`: ``eps``,
    ``candidates``, ``objective``, ``log_offset`` …), where it runs ``execution``
    (:class:`~sparsebtf.execution.Execution`: ``workers``, ``scheduler``, ``client``);
    ``keywords`` set their fields (``eps=1e-3``, ``workers=4``). A keyword that does not
    apply to the target (``eps`` to a ratio), or to one BTF (``crop``, ``checkpoint_dir``),
    is refused in one line; so is an argument of the wrong type (``options=5``, an array for
    a BTF: wrap it in :class:`~sparsebtf.data.btf.ArrayBTF`), with
    :class:`~sparsebtf.errors.ArgumentTypeError` (a ``TypeError``).
    """
    from .codec import encode as encode_tau
    from .codec import encode_many, encode_to_size
    from .codec.options import EncodeOptions
    from .data.btf import BTF
    from .execution import Execution
    from .open import BTF_ARGUMENT, check_btf_list

    if options is not None and not isinstance(options, EncodeOptions):
        raise wrong_type("encode", "options", "an EncodeOptions or None", options)
    if execution is not None and not isinstance(execution, Execution):
        raise wrong_type("encode", "execution", "an Execution or None", execution)
    if not isinstance(btf_or_btfs, BTF | str | os.PathLike):
        btf_or_btfs = check_btf_list("encode", "btf_or_btfs", btf_or_btfs,
                                     BTF_ARGUMENT + ", or a list of them")  # fmt: skip
    _check_model("encode", model)
    kind, value = parse_target(target)
    for key in ("tau", "target_bytes", "target_ratio"):
        if key in keywords:
            raise BTFInputError(f"encode: give the sparsity as target=..., not {key}= ("
                                + _SPELLINGS + ")")  # fmt: skip
    the_model = _model_of(model)
    if keywords.get("adaptive_patches") or (options is not None and options.adaptive_patches):
        return _encode_adaptive(btf_or_btfs, the_model, kind, value, options, execution,
                                keywords)  # fmt: skip
    if kind == "tau":
        goal: dict[str, Any] = {"tau": value}
    else:  # the coded file's bytes, unless the caller counts otherwise
        goal = {"target_bytes" if kind == "bytes" else "target_ratio": value,
                "budget": keywords.pop("budget", "stored"),
                "per_material": keywords.pop("per_material", True)}  # fmt: skip
    settings = {"options": options, "execution": execution, **keywords}
    if not isinstance(btf_or_btfs, BTF | str | os.PathLike):  # a list, checked above
        return encode_many(btf_or_btfs, the_model, **goal, **settings)
    btf = btf_or_btfs
    if isinstance(btf, str | os.PathLike):
        from .open import open_btf

        progress = keywords.get("progress", None if options is None else options.progress)
        btf = open_btf(btf, progress=progress)
    if kind == "tau":
        return encode_tau(btf, the_model, **goal, **settings)
    return encode_to_size(btf, the_model, **goal, **settings)


def _encode_adaptive(btf: Any, model: Model, kind: str, value: Any,
                     options: EncodeOptions | None, execution: Execution | None,
                     keywords: dict[str, Any]) -> Any:  # fmt: skip
    """:func:`encode` with ``adaptive_patches`` (:mod:`sparsebtf.codec.adaptive`): one BTF;
    a size or ratio counts the material's Table 4 bytes with its tree."""
    from .codec.adaptive import encode_adaptive
    from .data.btf import BTF

    if not isinstance(btf, BTF | str | os.PathLike):
        raise BTFInputError("adaptive_patches codes one BTF at a time for now; encode each")
    budget = keywords.pop("budget", "paper")
    per_material = keywords.pop("per_material", True)
    if kind != "tau" and (budget != "paper" or not per_material):
        raise BTFInputError("adaptive_patches: a size or ratio counts the material's Table 4 "
                            "bytes with its tree (budget='paper', per_material=True)")
    goal = ({"tau": value} if kind == "tau" else
            {"target_bytes" if kind == "bytes" else "target_ratio": value})  # fmt: skip
    return encode_adaptive(btf, model, **goal, options=options, execution=execution,
                           **keywords)


def decode(
    coded: CodedBTF | str | os.PathLike[str], model: Model | str | os.PathLike[str] | None = None
) -> DecodedBTF:
    """The decoded BTF of ``coded`` (Eq. 4), lazy: values are decoded from the codes when read
    (``.read(rows, cols, lights, views)``, ``.angular_image(l, v)``, ``.to_array()`` for the
    whole (H, W, L, V, 3) array), so a large BTF is never whole in memory.

    ``coded``: a :class:`~sparsebtf.model.CodedBTF` or a coded ``.h5`` file. Its model is
    ``model`` (a Model, a bundled name or a model file) if given, else the one attached, else
    the one the codes name (a bundled model by content hash, or the model file recorded at
    encoding); the wrong model is refused (:class:`~sparsebtf.errors.ModelMismatchError`).
    """
    from .model import CodedBTF, Model
    from .open import ARRAY_HINT
    from .patch_tree import AdaptiveCodedBTF
    from .runtime.adaptive import decoded_view
    from .runtime.dense import coded_btf_view
    from .storage.bundled import find_model

    _check_model("decode", model)
    if isinstance(coded, str | os.PathLike):
        from .storage import load_coded, load_coded_with_model

        if isinstance(model, Model):
            read = load_coded(coded, adaptive=True).attach(model)
        else:
            read = load_coded_with_model(coded, model, adaptive=True)
        return decoded_view(read) if isinstance(read, AdaptiveCodedBTF) else coded_btf_view(read)
    if isinstance(coded, AdaptiveCodedBTF):  # adaptive patch sizes: the NumPy reference
        if model is not None:
            coded.attach(_model_of(model, "decode"))
        elif coded.model is None:
            coded.attach(find_model(coded, None, coded.label))  # type: ignore[arg-type]
        return decoded_view(coded)
    if not isinstance(coded, CodedBTF):
        raise wrong_type("decode", "coded", "a coded BTF (sparsebtf.encode's result) or a coded "
                         ".h5 file's path", coded, ARRAY_HINT.split(":")[0] + " (nor a coded one)"
                         if is_array(coded) else "")  # fmt: skip
    if model is not None:
        coded.attach(_model_of(model, "decode"))
    elif coded.model is None:
        coded.attach(find_model(coded, None, coded.label))
    return coded_btf_view(coded)
