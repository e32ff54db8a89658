"""What a radiata pine has in front of the saw: twigs, needle fascicles and small branches.

Laid out from their own random stream (``numpy.random.default_rng([seed, 11])``),
so a scene without foliage draws exactly what it drew before foliage existed.

- twigs: 3-10 mm thick, 15-45 cm long, crossing the ranging region in front of
  the target branch;
- needle fascicles: three needles from one base, each about 1 mm thick and
  10-15 cm long (radiata pine), spread within 25 degrees of the fascicle's
  direction; based on the twigs when there are any, else free in the region;
- small branches: 12-30 mm thick, 30-80 cm long.

Every object lies in the foliage layer, at depths from ``(1 - foliage_front_rel)``
to 0.97 times the target's distance (a needle reaches up to 15 cm out of it);
pieces that would come within 4 cm of the camera plane are left out.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

from uav_depth.sim.geometry import BRANCH, NEEDLE, TWIG, Cylinder

NEEDLE_RADIUS_M = 0.0005
NEEDLE_LENGTH_M = (0.10, 0.15)
TWIG_RADIUS_M = (0.0015, 0.005)
SMALL_BRANCH_RADIUS_M = (0.006, 0.015)
NEAREST_Z_M = 0.04


class _Config(Protocol):
    width: int
    height: int
    focal_px: float
    branch_distance_m: float
    twigs: int
    fascicles: int
    small_branches: int
    foliage_front_rel: float
    seed: int


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _crossing(c: _Config, rng: np.random.Generator, length: float) -> tuple[np.ndarray, np.ndarray]:
    """Start and direction of a roughly fronto-parallel stick that passes through the region."""
    d = c.branch_distance_m
    z = d * float(rng.uniform(1.0 - c.foliage_front_rel, 0.97))
    hx = (c.width / 6.0) / c.focal_px * z
    hy = (c.height / 6.0) / c.focal_px * z
    through = np.array([float(rng.uniform(-1.2, 1.2)) * hx, float(rng.uniform(-1.2, 1.2)) * hy, z])
    ang = float(rng.uniform(0.0, math.pi))
    axis = _unit(np.array([math.cos(ang), math.sin(ang), float(rng.uniform(-0.3, 0.3))]))
    start = through - axis * length * float(rng.uniform(0.2, 0.8))
    return start, axis


def _keep(cyl: Cylinder) -> bool:
    end = cyl.p0 + cyl.axis * cyl.length
    return min(cyl.p0[2], end[2]) - cyl.radius > NEAREST_Z_M


def foliage(c: _Config) -> list[Cylinder]:
    """The foliage cylinders of ``c`` (empty when it has none)."""
    rng = np.random.default_rng([c.seed, 11])
    out: list[Cylinder] = []
    twigs: list[Cylinder] = []
    for _ in range(c.twigs):
        length = float(rng.uniform(0.15, 0.45))
        start, axis = _crossing(c, rng, length)
        cyl = Cylinder(start, axis, length, float(rng.uniform(*TWIG_RADIUS_M)), TWIG, 0,
                       float(rng.uniform(0.45, 0.65)))
        if _keep(cyl):
            twigs.append(cyl)
    out += twigs
    for _ in range(c.small_branches):
        length = float(rng.uniform(0.3, 0.8))
        start, axis = _crossing(c, rng, length)
        cyl = Cylinder(start, axis, length, float(rng.uniform(*SMALL_BRANCH_RADIUS_M)), BRANCH, 1,
                       float(rng.uniform(0.5, 0.7)))
        if _keep(cyl):
            out.append(cyl)
    for _ in range(c.fascicles):
        if twigs:
            host = twigs[int(rng.integers(len(twigs)))]
            base = host.p0 + host.axis * host.length * float(rng.uniform(0.05, 1.0))
            # Fascicles point outward and forward along the twig, as on a pine shoot.
            side = _unit(np.cross(host.axis, rng.standard_normal(3)))
            main = _unit(side + host.axis * float(rng.uniform(0.2, 0.8)))
        else:
            base, main = _crossing(c, rng, 0.0)
        albedo = float(rng.uniform(0.25, 0.4))
        for _ in range(3):
            spread = math.radians(float(rng.uniform(5.0, 25.0)))
            tilt = _unit(np.cross(main, rng.standard_normal(3)))
            axis = _unit(main * math.cos(spread) + tilt * math.sin(spread))
            cyl = Cylinder(base.copy(), axis, float(rng.uniform(*NEEDLE_LENGTH_M)), NEEDLE_RADIUS_M, NEEDLE, 1,
                           albedo * float(rng.uniform(0.9, 1.1)))
            if _keep(cyl):
                out.append(cyl)
    return out
