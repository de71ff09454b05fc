"""Seamlessly tiling 2D signals: filtered noise, cellular (Worley) noise, photographed textures.

Every signal here is periodic over the (H, W) tile so that parallax and shadow rays can wrap
around the edges without seams, and every random choice is drawn from the caller's
``numpy.random.Generator`` so a material is a pure function of its seed.

The photographs are the 512×512 greyscale textures bundled with scikit-image (``brick``,
``grass``, ``gravel``; no download). Photos do not tile, so we keep only their *periodic
component* (Moisan 2011, "Periodic plus smooth image decomposition"): the image minus the
smooth harmonic field that carries its edge discontinuities.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.spatial import cKDTree

__all__ = [
    "PHOTOS",
    "fbm",
    "filtered_noise",
    "periodic_component",
    "photo",
    "smoothstep",
    "standardize",
    "worley",
]

PHOTOS = ("brick", "grass", "gravel")


def smoothstep(edge0: float, edge1: float, x: np.ndarray) -> np.ndarray:
    """Hermite step from 0 at ``edge0`` to 1 at ``edge1`` (C¹, so derived normals stay smooth)."""
    t = np.clip((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def standardize(x: np.ndarray) -> np.ndarray:
    """Zero mean, unit standard deviation (a constant field maps to zeros)."""
    x = np.asarray(x, dtype=np.float64)
    sd = float(x.std())
    return (x - x.mean()) / sd if sd > 1e-12 else np.zeros_like(x)


def _freqs(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Row and column frequencies in cycles per texel, broadcastable to ``shape``."""
    fy = np.fft.fftfreq(shape[0])[:, None]
    fx = np.fft.fftfreq(shape[1])[None, :]
    return fy, fx


def filtered_noise(
    shape: tuple[int, int],
    rng: np.random.Generator,
    sigma: float,
    *,
    angle: float = 0.0,
    stretch: float = 1.0,
) -> np.ndarray:
    """Periodic Gaussian-filtered white noise, standardised.

    ``sigma`` is the correlation length in texels across the grain; ``stretch`` > 1 elongates
    the features by that factor along ``angle`` (radians from the +column axis, counter-
    clockwise with rows pointing down), which gives fibres, wood pores and streaks.
    """
    white = rng.standard_normal(shape)
    fy, fx = _freqs(shape)
    # Rows point down in the image, so the +y axis of the tangent frame is −row.
    along = fx * np.cos(angle) - fy * np.sin(angle)
    across = fx * np.sin(angle) + fy * np.cos(angle)
    f2 = (along * stretch) ** 2 + across**2
    gain = np.exp(-2.0 * np.pi**2 * sigma**2 * f2)
    out = np.real(np.fft.ifft2(np.fft.fft2(white) * gain))
    return standardize(out)


def fbm(
    shape: tuple[int, int],
    rng: np.random.Generator,
    sigma: float,
    octaves: int = 4,
    gain: float = 0.5,
    **kwargs: float,
) -> np.ndarray:
    """Fractal sum of :func:`filtered_noise` octaves (each half the scale), standardised."""
    out = np.zeros(shape)
    amp = 1.0
    for k in range(octaves):
        out += amp * filtered_noise(shape, rng, max(sigma / 2**k, 0.5), **kwargs)
        amp *= gain
    return standardize(out)


def worley(
    shape: tuple[int, int], rng: np.random.Generator, n_points: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Periodic cellular noise: distances (texels) to the nearest and second-nearest of
    ``n_points`` random sites, and the index of the nearest site.

    F1 gives rounded cells (pebbles, leather grains); F2 − F1 is small along cell borders,
    which gives cracks and creases.
    """
    h, w = shape
    n = max(int(n_points), 2)
    sites = rng.random((n, 2)) * np.array([h, w], dtype=np.float64)
    sites = np.mod(sites, [h, w])
    sites = np.minimum(sites, np.nextafter(np.array([h, w], dtype=np.float64), 0))
    tree = cKDTree(sites, boxsize=[h, w])
    rr, cc = np.mgrid[0:h, 0:w]
    grid = np.stack([rr.ravel(), cc.ravel()], axis=1).astype(np.float64)
    dist, idx = tree.query(grid, k=2)
    f1 = dist[:, 0].reshape(shape)
    f2 = dist[:, 1].reshape(shape)
    return f1, f2, idx[:, 0].reshape(shape)


def periodic_component(img: np.ndarray) -> np.ndarray:
    """Moisan's periodic component of a 2D image: seamless when tiled, same content inside."""
    u = np.asarray(img, dtype=np.float64)
    h, w = u.shape
    v = np.zeros_like(u)
    v[0, :] += u[-1, :] - u[0, :]
    v[-1, :] += u[0, :] - u[-1, :]
    v[:, 0] += u[:, -1] - u[:, 0]
    v[:, -1] += u[:, 0] - u[:, -1]
    q = np.arange(h)[:, None]
    r = np.arange(w)[None, :]
    denom = 2.0 * np.cos(2.0 * np.pi * q / h) + 2.0 * np.cos(2.0 * np.pi * r / w) - 4.0
    denom[0, 0] = 1.0
    s_hat = np.fft.fft2(v) / denom
    s_hat[0, 0] = 0.0
    return u - np.real(np.fft.ifft2(s_hat))


@lru_cache(maxsize=len(PHOTOS))
def _load_photo(name: str) -> np.ndarray:
    from skimage import data

    img = np.asarray(getattr(data, name)(), dtype=np.float64) / 255.0
    img.setflags(write=False)
    return img


def photo(
    name: str,
    shape: tuple[int, int],
    rng: np.random.Generator,
    crop: int = 256,
    stretch: tuple[float, float] = (1.0, 1.0),
) -> np.ndarray:
    """A seamless, standardised detail layer cut from a bundled scikit-image photograph.

    A random ``crop``-texel window (scaled per axis by ``stretch`` = (rows, cols), so that e.g.
    a tall window squeezed to the tile gives streaks along the rows) is resampled to ``shape``
    and made periodic.
    """
    from skimage.transform import resize

    if name not in PHOTOS:
        raise ValueError(f"unknown photo {name!r}; bundled: {', '.join(PHOTOS)}")
    src = _load_photo(name)
    ch = int(min(src.shape[0], max(8, round(crop * stretch[0]))))
    cw = int(min(src.shape[1], max(8, round(crop * stretch[1]))))
    r0 = int(rng.integers(0, src.shape[0] - ch + 1))
    c0 = int(rng.integers(0, src.shape[1] - cw + 1))
    window = src[r0 : r0 + ch, c0 : c0 + cw]
    small = resize(window, shape, order=1, anti_aliasing=True, mode="reflect")
    return standardize(periodic_component(small))
