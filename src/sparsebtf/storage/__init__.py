"""Model and coded-BTF files (HDF5) and the paper's storage accounting (Table 4).

* :func:`save_model` / :func:`load_model` — the trained dictionaries, float64, content-hashed.
* :func:`save_coded` / :func:`load_coded` — one material's sparse codes (binary16 values;
  schema 3: location tables and value byte planes, compressed losslessly; schema 2: 3-byte packed
  locations), statistics and directions; checked against its model's hash.
* adaptive patch sizes: schema 4 of the coded file (:mod:`.adaptive_file`), written by
  :func:`save_coded` and read by ``load_coded(path, adaptive=True)``.
* :func:`storage_report` / :func:`paper_storage` — bytes as counted by ``btf4Dcomp`` (Table 4)
  and, for coded BTFs, the bytes the file stores (:func:`stored_bytes`).

Every write is atomic; every read error is a :class:`~sparsebtf.errors.FileFormatError` or
:class:`~sparsebtf.errors.ModelMismatchError` naming the file and field. Layouts:
``docs/format.md``.
"""

from __future__ import annotations

from ..learning.cost import channel_storage, location_width
from .accounting import MIB, paper_storage, storage_report, storage_summary, stored_bytes
from .coded_file import (
    CODED_FORMAT,
    CODED_SCHEMA_VERSION,
    load_coded,
    load_coded_with_model,
    save_coded,
)
from .locations import pack_locations, unpack_locations
from .model_file import MODEL_FORMAT, MODEL_SCHEMA_VERSION, load_model, save_model

# registers the reader and writers of adaptive patch sizes (schema 4) with the coded file's
from . import adaptive_file  # noqa: F401  isort: skip

__all__ = [
    "CODED_FORMAT",
    "CODED_SCHEMA_VERSION",
    "MIB",
    "MODEL_FORMAT",
    "MODEL_SCHEMA_VERSION",
    "channel_storage",
    "load_coded",
    "load_coded_with_model",
    "load_model",
    "location_width",
    "pack_locations",
    "paper_storage",
    "save_coded",
    "save_model",
    "storage_report",
    "storage_summary",
    "stored_bytes",
    "unpack_locations",
]
