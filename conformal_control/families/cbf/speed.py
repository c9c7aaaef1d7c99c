"""The speed set of the velocity safety filters: a polygon inscribed in the speed disc."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["speed_polygon"]


def speed_polygon(sides: int, v_max: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The speed set ``S v <= s`` and its vertices.

    ``sides >= 3``: the regular polygon inscribed in the disc of radius ``v_max`` (side
    normals at angles ``(k + 1/2) 2 pi / sides``, vertices on the circle); ``sides = 0``:
    the box ``|v_x|, |v_y| <= v_max``. Returns ``(S, s, vertices, R)`` with ``R`` the
    radius of the smallest disc centred at 0 containing the set.
    """
    if sides:
        ang = 2.0 * np.pi * (np.arange(sides) + 0.5) / sides
        S = np.column_stack([np.cos(ang), np.sin(ang)])
        s = np.full(sides, v_max * math.cos(math.pi / sides))
        va = 2.0 * np.pi * np.arange(1, sides + 1) / sides
        verts = v_max * np.column_stack([np.cos(va), np.sin(va)])
        return S, s, verts, float(v_max)
    S = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    s = np.full(4, float(v_max))
    verts = v_max * np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
    return S, s, verts, math.sqrt(2.0) * v_max
