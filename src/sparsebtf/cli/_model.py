"""The ``-m/--model`` argument: a model file or a bundled model's name (default: the bundled
``release`` model), and the one-line refusals when a BTF does not fit a model."""

from __future__ import annotations

from typing import Any

from ..errors import SparseBTFError

__all__ = ["MODEL_HELP", "check_fits", "model_label", "open_model_arg"]

MODEL_HELP = (
    "model file from 'sparsebtf train' / 'import-release', or a bundled model's name "
    "(see 'sparsebtf models')"
)


def open_model_arg(spec: str | None) -> Any:
    """The model ``-m`` names (None: the default bundled model)."""
    from ..storage.bundled import open_model

    return open_model(spec)


def model_label(spec: str | None, model: Any) -> str:
    """How errors and reports name the model: the bundled name or the file given."""
    from ..storage.bundled import bundled_name

    name = bundled_name(model.content_hash)
    if name is not None and (spec is None or spec == name):
        return f"bundled model '{name}'"
    return f"model {spec}"


def check_fits(btf: Any, model: Any, label: str, source: str) -> None:
    """Refuse, in one line, a BTF whose directions or size the model cannot code.

    Directions: the model's ensembles are over its direction tables only, so the line names
    the ``sparsebtf train`` command that makes a model for the BTF's own. Size: H and W must be
    multiples of the patch, and the line gives the ``--crop`` that makes them so.
    """
    nl, nv = len(btf.lights), len(btf.views)
    if not (btf.lights.equals(model.lights) and btf.views.equals(model.views)):
        kind = btf.lights.name if nl == nv else "custom"
        raise SparseBTFError(
            f"{source} has {nl} lights x {nv} views ({kind}), but {label} covers "
            f"{len(model.lights)} x {len(model.views)} ({model.lights.name}) directions only; "
            f"train a model for these directions: sparsebtf train {source} [more BTFs] -o "
            f"my-model.h5 --patch {model.patch}, then encode with -m my-model.h5"
        )
    p = model.patch
    if btf.height % p or btf.width % p:
        h, w = btf.height - btf.height % p, btf.width - btf.width % p
        size = f"{source} is {btf.height}x{btf.width} texels"
        if not (h and w):
            raise SparseBTFError(f"{size}, smaller than one {p}x{p} patch of {label}")
        raise SparseBTFError(
            f"{size}, not a multiple of the {p}x{p} patches of {label}; add --crop 0:{h},0:{w} "
            f"to code the largest part that is"
        )
