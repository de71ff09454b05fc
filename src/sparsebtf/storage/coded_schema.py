"""What a coded file of each schema must carry: one table, checked before anything is read.

The readers of :mod:`.coded_file` and :mod:`.coded_streams` demand what every schema has
(``model_hash``, the sizes, ``codes/``, ``stats/mean`` …) as they read it. Some fields have a
fallback for files written before they existed: ``name`` (the file's stem), ``channels`` (the
groups under ``codes/``), ``params_json`` and ``attrs_json`` (none), ``stats@eps`` (the release's
1e-5), ``stats/bound`` (no clamp). A
file that says it is schema 3 was written after all of them existed, so a missing one is
damage, not age: decoding it with the fallback would give other values (no clamp, another
log offset) and exit 0. :data:`REQUIRED_SINCE` names each such field with the first schema
that always carries it; :func:`check_required` refuses a file that lacks one, in one line that
names the file, the field and the schema it claims.

A schema-3 file may state that it has no bound (statistics without one, e.g. imported from the
authors' release): ``stats@clamp = "none"`` (:data:`NO_CLAMP`) in place of ``stats/bound``.
"""

from __future__ import annotations

from dataclasses import dataclass

import h5py

from .._h5check import as_str
from ..errors import FileFormatError

__all__ = ["NO_CLAMP", "REQUIRED_SINCE", "Required", "check_required"]

#: ``stats`` attribute of a schema-3 file without ``stats/bound``: its decoders do not clamp.
NO_CLAMP = ("clamp", "none")


@dataclass(frozen=True)
class Required:
    """One field a coded file must carry from schema ``since`` on.

    group : the HDF5 group holding it ("" for the root; "codes/*" for each channel's group,
        "sizes/*/*" for each patch size's channel groups of schema 4).
    name : the attribute or dataset name; kind : "attribute" or "dataset".
    unless : an attribute (name, value) of ``group`` that states the field's absence.
    """

    group: str
    name: str
    kind: str
    since: int
    unless: tuple[str, str] | None = None


#: The fields with a fallback for older files, and the first schema that always has them.
REQUIRED_SINCE: tuple[Required, ...] = (
    Required("", "name", "attribute", 3),
    Required("", "channels", "attribute", 3),
    Required("", "library_version", "attribute", 3),
    Required("", "params_json", "attribute", 3),
    Required("", "attrs_json", "attribute", 3),
    Required("codes/*", "n_points", "attribute", 3),
    Required("codes/*", "nnz", "attribute", 3),
    Required("codes/*", "location_bytes", "attribute", 3),
    Required("codes/*", "n_dictionaries", "attribute", 3),
    # schema 4 (adaptive patch sizes): the same counts in each size's channel groups
    *(Required("sizes/*/*", n, "attribute", 4)
      for n in ("n_points", "nnz", "location_bytes", "n_dictionaries")),
    Required("stats", "eps", "attribute", 3),
    Required("stats", "bound", "dataset", 3, unless=NO_CLAMP),
    *(Required(g, n, k, 3) for g in ("lights", "views")
      for n, k in (("name", "attribute"), ("theta", "dataset"), ("phi", "dataset"))),
)  # fmt: skip


def check_required(f: h5py.File, schema: int, where: str) -> None:
    """Refuse a file of ``schema`` that lacks a field :data:`REQUIRED_SINCE` gives it.

    Groups that are missing altogether are left to the reader (it names them); ``where`` is
    the file's name for the message.
    """
    for req in REQUIRED_SINCE:
        if schema < req.since:
            continue
        for path in _groups(f, req.group):
            g = f[path] if path else f
            if not isinstance(g, h5py.Group):
                continue  # the reader says what it expected there
            present = req.name in (g.attrs if req.kind == "attribute" else g)
            if present or _states_absence(g, req.unless):
                continue
            at = f"{where}/{path}" if path else where
            raise FileFormatError(
                f"{at}: missing {req.kind} {req.name!r}, which every schema-{req.since} coded "
                f"file carries (this file says schema {schema}); the file is damaged or was "
                "edited: write it again from its source"
            )


def _groups(f: h5py.File, pattern: str) -> list[str]:
    """The paths ``pattern`` names in ``f`` that exist ("codes/*": every channel group;
    "sizes/*/*": every channel group of every patch size)."""
    if pattern.endswith("/*"):
        return [f"{parent}/{name}" for parent in _groups(f, pattern[:-2])
                if isinstance(f[parent], h5py.Group) for name in f[parent]]  # fmt: skip
    return [pattern] if pattern == "" or pattern in f else []


def _states_absence(g: h5py.Group, unless: tuple[str, str] | None) -> bool:
    if unless is None or unless[0] not in g.attrs:
        return False
    try:
        return as_str(g.attrs[unless[0]]) == unless[1]
    except (TypeError, ValueError):
        return False
