"""Test materials and coded stores shared by the highlight store's tests
(``test_highlights.py``, ``test_highlight_file.py``; their fixtures are in ``conftest.py``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sparsebtf.codec import encode, encode_levels
from sparsebtf.data.btf import ArrayBTF

from .conftest import smooth_btf
from .test_highlight_decode import random_store

LEVELS = [(16, 4, 4), (32, 8, 8), (64, 16, 16)]


def glossy_btf(seed: int = 3) -> ArrayBTF:
    """``smooth_btf`` with sharp highlights: a few (texel, light, view) values × 40–200, the
    kind a log-domain code reaches slowly."""
    b = smooth_btf(seed)
    data = np.array(b.to_array())
    rng = np.random.default_rng(seed)
    hit = rng.random(data.shape[:4]) < 0.01
    data[hit] *= rng.uniform(40, 200, (int(hit.sum()), 1)).astype(np.float32)
    return ArrayBTF(data, b.lights, b.views, name="glossy")


def tinted_btf(seed: int = 4) -> ArrayBTF:
    """``smooth_btf`` with copper highlights: at a few (texel, light, view) nodes, 5–50 times
    one colour added (a metal's highlight takes the metal's colour)."""
    b = smooth_btf(seed)
    data = np.array(b.to_array())
    rng = np.random.default_rng(seed)
    hit = rng.random(data.shape[:4]) < 0.02
    amp = rng.uniform(5, 50, (int(hit.sum()), 1))
    data[hit] += (amp * np.array([0.95, 0.64, 0.54])).astype(np.float32)
    return ArrayBTF(data, b.lights, b.views, name="copper")


def glossy_levels(model) -> list:
    """``glossy_btf`` coded at ``LEVELS`` with the store (``levels``)."""
    return encode_levels(glossy_btf(), model, LEVELS, eps=0.0, highlights=True, progress=False,
                         allow_below_training=True)  # fmt: skip


def first_tinted_level(model):
    """A level whose store is tinted: the lowest level of ``tinted_btf`` (its highlights share
    one colour) that takes one (``tinted_level``)."""
    coded = encode_levels(tinted_btf(), model, LEVELS, eps=0.0, highlights=True,
                          progress=False, allow_below_training=True)  # fmt: skip
    c = next(c for c in coded if c.params["highlights"]["tinted"])
    assert c.highlights.tints is not None
    return c


def lobed_material(model):
    """A coded material whose store has lobes: random ones on the codes of ``smooth_btf(6)``,
    with the first point's entries of a random store (``lobed``)."""
    c = encode(smooth_btf(6), model, tau=(32, 8, 8), eps=0.0, progress=False)
    rng = np.random.default_rng(2)
    n = (c.n_points, c.patch**2)
    lobes = np.concatenate([rng.uniform(-0.4, 0.4, (*n, 3)), np.log(rng.uniform(0.1, 0.4, (*n, 2))),
                            rng.uniform(0, 2, (*n, 3))], axis=2).astype(np.float16)  # fmt: skip
    return replace(c, highlights=replace(random_store(c, share=0.1, scale=0.5), lobes=lobes))
