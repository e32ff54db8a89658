"""Surface textures of the synthetic scenes: tileable multi-scale noise, laid so that no row repeats it.

Textures are attached to surfaces (arc length and axial position on a cylinder,
metric X/Y on the background plane), so both views see the same bark at the same
place. Tiles are laid at irrational angles: a square-laid tile repeats inside
SGBM's search range and SGBM matches the wrong repeat with full confidence.
"""

from __future__ import annotations

import math

import numpy as np

TEX_SIZE = 512
#: Metres one bark (True) / foliage (False) texture tile spans at texture_scale 1.
TEX_M = {True: 0.25, False: 3.0}
BG_ANGLE = math.atan((math.sqrt(5.0) - 1.0) / 2.0)
BG_COS, BG_SIN = np.float32(math.cos(BG_ANGLE)), np.float32(math.sin(BG_ANGLE))
#: Along an image row the tilted tile comes back close to itself (within 9% of a tile
#: across the row) only after sqrt(3**2 + 5**2) tiles: the 3/5 convergent of the tangent.
BG_REPEAT_TILES = math.sqrt(34.0)
BARK_ANGLE = math.atan((3.0 - math.sqrt(5.0)) / 2.0)     # tangent 1/phi**2, about 20.9 degrees
BARK_COS, BARK_SIN = math.cos(BARK_ANGLE), math.sin(BARK_ANGLE)


def periodic_noise(rng: np.random.Generator, size: int, sigma_u: float, sigma_v: float) -> np.ndarray:
    """Tileable smooth noise (size, size) in 0..1, anisotropic Gaussian spectrum."""
    white = rng.standard_normal((size, size))
    fy = np.fft.fftfreq(size)[:, None]
    fx = np.fft.fftfreq(size)[None, :]
    spec = np.exp(-2 * (math.pi ** 2) * ((fx * sigma_u) ** 2 + (fy * sigma_v) ** 2))
    field = np.real(np.fft.ifft2(np.fft.fft2(white) * spec))
    field -= field.min()
    field /= max(field.max(), 1e-9)
    return field


def texture(rng: np.random.Generator, size: int, bark: bool) -> np.ndarray:
    """Multi-scale texture in 0..1: bark is stretched along the axis (v), foliage is isotropic."""
    if bark:
        parts = [(0.5, periodic_noise(rng, size, 1.5, 10.0)), (0.3, periodic_noise(rng, size, 5.0, 30.0)),
                 (0.2, periodic_noise(rng, size, 0.8, 2.0))]
    else:
        parts = [(0.45, periodic_noise(rng, size, 2.0, 2.0)), (0.35, periodic_noise(rng, size, 8.0, 8.0)),
                 (0.2, periodic_noise(rng, size, 1.0, 1.0))]
    tex = sum(w * p for w, p in parts)
    tex = (tex - tex.min()) / max(tex.max() - tex.min(), 1e-9)
    return tex.astype(np.float32)


def wrap(x: np.ndarray) -> np.ndarray:
    """``np.mod(x, TEX_SIZE)`` bit for bit, about five times faster.

    Dividing by a power of two and flooring are exact, so ``x - size * k`` is the
    exact remainder rounded once, which is what numpy's fmod-and-adjust returns.
    """
    return x - float(TEX_SIZE) * np.floor(x * (1.0 / TEX_SIZE))
