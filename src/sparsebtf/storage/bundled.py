"""Models shipped inside the package, and how a model name or a coded file finds its model.

Bundled models are the model files in the package folder ``sparsebtf/models/`` (package data,
in the wheel too); a model's name is its file stem. Today there is one:

* ``release`` — the authors' Y/U/V ensembles (K = 8 per channel, 10×10 texel patches, the
  151 UBO2014 directions), trained on 18 measured UBO2014 materials (paper §4), MIT-licensed
  (``LICENSE-SparseBTF`` beside it). Built from the authors' files by
  :mod:`sparsebtf.storage.release_bundle`; ``sparsebtf/models/PROVENANCE.md`` says how.

:func:`open_model` turns what a user gives (nothing, a bundled name, a file) into a model;
:func:`find_model` finds the model of a coded file: the one given, else the bundled model with
the content hash the codes name, else the model file recorded at encoding.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .._h5check import read_json_attr, read_str_attr
from ..errors import FileFormatError, ModelMismatchError
from ..model import MODEL_NAMERS
from ._common import open_checked

if TYPE_CHECKING:
    from ..model import CodedBTF, Model

__all__ = [
    "DEFAULT_MODEL",
    "BundledModel",
    "bundled_models",
    "find_model",
    "load_bundled",
    "models_dir",
    "open_model",
]

#: The model ``sparsebtf encode`` uses when no ``-m`` is given.
DEFAULT_MODEL = "release"


def models_dir() -> Path:
    """The package folder holding the bundled model files."""
    return Path(str(resources.files("sparsebtf") / "models"))


@dataclass(frozen=True)
class BundledModel:
    """A bundled model file, described from its attributes (no dictionary is read)."""

    name: str
    path: Path
    content_hash: str
    params: dict[str, Any]
    provenance: dict[str, Any]

    def describe(self) -> dict[str, Any]:
        """What ``sparsebtf models`` lists: name, hash, channels, K, patch, directions, τ_l,
        source and licence."""
        m = load_bundled(self.name)
        return {
            "name": self.name,
            "content_hash": self.content_hash,
            "channels": list(m.channels),
            "n_dictionaries": {ch: m.n_dictionaries(ch) for ch in m.channels},
            "patch": m.patch,
            "mode_sizes": list(m.mode_sizes),
            "directions": {
                "lights": {"name": m.lights.name, "count": len(m.lights)},
                "views": {"name": m.views.name, "count": len(m.views)},
            },
            "tau_train": m.tau_train or None,
            "source": self.provenance.get("source", ""),
            "licence": self.provenance.get("licence", ""),
            "file": str(self.path),
            "file_bytes": self.path.stat().st_size,
        }


@functools.cache
def _registry(folder: str) -> dict[str, BundledModel]:
    from .model_file import _SUPPORTED, MODEL_FORMAT

    out: dict[str, BundledModel] = {}
    for path in sorted(Path(folder).glob("*.h5")):
        with open_checked(path, MODEL_FORMAT, _SUPPORTED) as f:
            where = str(path)
            out[path.stem] = BundledModel(
                path.stem,
                path,
                read_str_attr(f, "content_hash", where),
                read_json_attr(f, "params_json", where),
                read_json_attr(f, "provenance_json", where),
            )
    return out


def bundled_models() -> dict[str, BundledModel]:
    """The bundled models by name (empty when the package was installed without them)."""
    return dict(_registry(str(models_dir())))


@functools.cache
def _load(path: str) -> Model:
    from .model_file import load_model

    model = load_model(path)
    model.file = None  # found by name and hash, not by a path into the installation
    return model


def load_bundled(name: str = DEFAULT_MODEL) -> Model:
    """A bundled model by name (loaded once per process)."""
    models = bundled_models()
    if name not in models:
        have = ", ".join(models) or "none: this installation lacks sparsebtf/models/*.h5"
        raise FileFormatError(f"no bundled model named {name!r} (bundled: {have})")
    return _load(str(models[name].path))


def open_model(spec: str | os.PathLike[str] | None = None) -> Model:
    """The model a user names: ``None`` → the default bundled model (:data:`DEFAULT_MODEL`);
    an existing file → that model file; otherwise a bundled model's name."""
    if spec is None:
        return load_bundled(DEFAULT_MODEL)
    if Path(spec).exists():
        from .model_file import load_model

        return load_model(spec)
    name = str(spec)
    models = bundled_models()
    if name in models:
        return load_bundled(name)
    have = ", ".join(models) or "none"
    raise FileFormatError(f"{name}: no such model file, and no bundled model of that name "
                          f"(bundled: {have})")  # fmt: skip


def bundled_name(content_hash: str) -> str | None:
    """The name of the bundled model with this content hash, if any."""
    return next((m.name for m in bundled_models().values() if m.content_hash == content_hash),
                None)  # fmt: skip


MODEL_NAMERS.append(bundled_name)  # messages name bundled models (model.model_text)


def find_model(
    coded: CodedBTF, model: str | os.PathLike[str] | None = None, where: str | None = None
) -> Model:
    """The model of ``coded``: ``model`` (a file or bundled name) if given; else the bundled
    model whose content hash the codes name; else the model file recorded at encoding.

    The caller attaches it (which checks the hash). ``where`` names the coded file in errors.
    """
    if model is not None:
        return open_model(model)
    name = bundled_name(coded.model_hash)
    if name is not None:
        return load_bundled(name)
    recorded = coded.model_file
    # A path read from a file is followed only to a regular file (a FIFO there would block).
    if recorded and Path(recorded).is_file():
        from .model_file import load_model

        return load_model(recorded)
    if not recorded:
        why = "it records no model file"
    elif Path(recorded).exists():
        why = (f"the model file it recorded, {recorded}, is not a regular file (a folder, "
               "FIFO or device)")  # fmt: skip
    else:
        why = f"the model file it recorded, {recorded}, does not exist"
    raise ModelMismatchError(
        f"{where or coded.label}: coded with model {coded.model_hash[:12]}…, which is not a "
        f"bundled model, and {why}; give the model file it was coded with (--model MODEL.h5 on "
        "the command line, model_path=... in Python)"
    )
