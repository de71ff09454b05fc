"""The paper's display mapping for BTF images (§4: "gamma-mapped using a·I^(1/γ)")."""

from __future__ import annotations

import numpy as np

__all__ = ["tone_map"]


def tone_map(image: np.ndarray, a: float = 1.3, gamma: float = 1.8) -> np.ndarray:
    """Display mapping a·I^(1/γ), clipped to [0, 1]; negative and NaN values map to 0."""
    x = np.nan_to_num(np.asarray(image, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    return np.clip(a * np.maximum(x, 0.0) ** (1.0 / gamma), 0.0, 1.0)
