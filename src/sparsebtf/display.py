"""The paper's display mapping for BTF images, the one rule every displayed image and
display-domain metric of the project uses.

The paper shows its Figures 4–6 "gamma-mapped using I_out = a·I_in^(−γ), a = 1.3, γ = 1.8"
(§4). A negative exponent would turn bright values dark; the images are ordinary gamma
curves, so the exponent is 1/γ (the text's −γ is a typo)::

    I_out = clip(a · max(I_in, 0)^(1/γ), 0, 1),   a = DISPLAY_SCALE, γ = DISPLAY_GAMMA

on linear RGB, per channel. Users: :func:`tone_map` for images (figures, ``sparsebtf blend``,
the synthetic-material previews) and the metric ``mse_display`` of
:func:`sparsebtf.metrics.compare` and :func:`sparsebtf.evaluation.scoring.score_many` — the MSE
of values as a viewer sees them, where a firework of 1e3 counts as much as any other clipped
white, unlike the linear-RGB MSE that highlights dominate on high-dynamic-range materials.
"""

from __future__ import annotations

import numpy as np

__all__ = ["DISPLAY_GAMMA", "DISPLAY_SCALE", "tone_map"]

#: The paper's a in I_out = a·I_in^(1/γ).
DISPLAY_SCALE = 1.3
#: The paper's γ in I_out = a·I_in^(1/γ).
DISPLAY_GAMMA = 1.8


def tone_map(
    image: np.ndarray,
    a: float = DISPLAY_SCALE,
    gamma: float = DISPLAY_GAMMA,
    dtype: type = np.float64,
) -> np.ndarray:
    """Display mapping a·I^(1/γ), clipped to [0, 1]; negative and NaN values map to 0.

    ``image``: linear RGB of any shape; returns the same shape in ``dtype`` (float32 halves
    the memory of the metrics' tiles; its rounding, ~6e-8, is far below any coding error).
    """
    x = np.array(image, dtype=dtype)  # a copy: the caller's array is left as it is
    np.nan_to_num(x, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
    np.maximum(x, 0, out=x)
    x **= dtype(1.0 / gamma)
    x *= dtype(a)
    return np.clip(x, 0.0, 1.0, out=x)
