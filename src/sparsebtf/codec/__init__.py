"""The SparseBTF codec: train a model once (§3.2), encode any BTF on it (§3.3), to a target size
by rate control (beyond §3.3).

>>> model = train([btf_a, btf_b], tau_train=(256, 32, 32))           # doctest: +SKIP
>>> coded = encode(btf_c, model, tau=(885, 64, 64), eps=1e-5)          # doctest: +SKIP
>>> coded = encode(btf_c, model, options=EncodeOptions(eps=0.0), workers=4)  # doctest: +SKIP

Decoding reads codes and lives in :mod:`sparsebtf.runtime` (``coded_btf_view``, Eq. 4–6).
Everything streams: statistics by view block, data points by patch. :func:`encode_many` codes
many BTFs in one run. Every encoder is one engine (:func:`.jobs.run_plan`) with a target (τ
levels or rate targets), :class:`EncodeOptions` and an :class:`~sparsebtf.execution.Execution`
(``client=`` / ``scheduler=`` / ``workers=``: a Dask cluster, ``docs/distributed.md``);
:func:`train` takes :class:`TrainOptions` and an execution likewise (:mod:`.options`).
"""

from __future__ import annotations

from ..model import parse_tau
from .encode import encode, encode_levels
from .many import encode_many, output_name
from .options import WEIGHTINGS, EncodeOptions, TrainOptions
from .rate import encode_rate_levels, encode_to_size, material_target_bytes
from .train import train

__all__ = [
    "WEIGHTINGS",
    "EncodeOptions",
    "TrainOptions",
    "encode",
    "encode_levels",
    "encode_many",
    "encode_rate_levels",
    "encode_to_size",
    "material_target_bytes",
    "output_name",
    "parse_tau",
    "train",
]
