"""The default region of interest: one definition for the daemon's ranging and the simulator."""

from __future__ import annotations


def center_roi(width: int, height: int) -> tuple[int, int, int, int]:
    """The central third of a width x height image, (x0, y0, x1, y1) px."""
    return (width // 3, height // 3, 2 * width // 3, 2 * height // 3)
