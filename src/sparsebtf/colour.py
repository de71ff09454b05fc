"""Colour transforms of the pipeline: analog BT.601 RGB ⇄ YUV (paper §3.1).

Applied to log values by the preprocessing (:mod:`sparsebtf.points.preprocessing`), undone by
every decoder (:mod:`sparsebtf.runtime`) and by the readers of the authors' release
(:mod:`sparsebtf.formats.ubo2014`). The forward matrix is the release's
(``DataBTF4D.inl``); :data:`YUV_TO_RGB` is its exact inverse (``np.linalg.inv``: a float64
round trip at rounding level) and :data:`YUV_TO_RGB_RELEASE` the rounded inverse of the
release's shader, for renderers that must match it bit for bit.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "RGB_TO_YUV",
    "RGB_TO_YUV_F32",
    "YUV_TO_RGB",
    "YUV_TO_RGB_RELEASE",
    "rgb_to_yuv",
    "yuv_to_rgb",
]

#: Analog BT.601 RGB → YUV, applied to log values (release: ``DataBTF4D.inl``).
RGB_TO_YUV = np.array(
    [
        [0.299, 0.587, 0.114],
        [-0.14713, -0.28886, 0.436],
        [0.615, -0.51499, -0.10001],
    ]
)
#: :data:`RGB_TO_YUV` in float32, as the compiled preprocessing passes take it.
RGB_TO_YUV_F32 = RGB_TO_YUV.astype(np.float32)
#: Exact inverse of :data:`RGB_TO_YUV`.
YUV_TO_RGB = np.linalg.inv(RGB_TO_YUV)
#: The release shader's rounded inverse (|inv·fwd − I| ≤ 1.6e-5).
YUV_TO_RGB_RELEASE = np.array(
    [
        [1.0, 0.0, 1.13983],
        [1.0, -0.39465, -0.5806],
        [1.0, 2.03211, 0.0],
    ]
)



def rgb_to_yuv(x: np.ndarray) -> np.ndarray:
    """Colour transform on the last axis (size 3)."""
    return x @ RGB_TO_YUV.T.astype(x.dtype, copy=False)


def yuv_to_rgb(x: np.ndarray, release_matrix: bool = False) -> np.ndarray:
    """Inverse colour transform on the last axis; ``release_matrix`` uses the shader's rounding."""
    m = YUV_TO_RGB_RELEASE if release_matrix else YUV_TO_RGB
    return x @ m.T.astype(x.dtype, copy=False)
