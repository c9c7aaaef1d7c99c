"""A robot's start and goals as users type them: fractions of the scene, metres or pixels.

One form everywhere a task is given (``--start``/``--goal``, a robots file's start and
goals, :func:`conformal_control.run`'s ``start``/``goal``,
:func:`~conformal_control.data.load_scene`):

* ``0.05,0.5`` (two bare numbers) - fractions of the scene's **frame**: the reference
  image's width and height on SDD scenes, the recording's walkable box on ETH/UCY ones
  (:func:`~conformal_control.data.scenes.walkable_box`);
* ``3.2m,1.0m`` - metres, in the scene's own coordinates (``conformal-control scenes``
  prints each scene's frame in metres);
* ``120px,300px`` - pixels of the reference image (SDD scenes).

Both numbers carry the same unit. In Python a position is also a pair of numbers
(fractions), a pair of strings with a unit (``("3.2m", "1m")``) or a :class:`Position`.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.exceptions import InputError

__all__ = [
    "POSITION_UNITS",
    "Position",
    "parse_position",
    "parse_positions",
    "scene_frame",
    "scene_position",
    "to_metres",
]

#: The units a position may be typed in (bare numbers are fractions of the scene's frame).
POSITION_UNITS = ("fraction", "m", "px")

_NUMBER = r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"
_QUANTITY = re.compile(rf"^\s*({_NUMBER})\s*(m|px)?\s*$")


@dataclass(frozen=True)
class Position:
    """A point as typed: two numbers and their unit.

    Attributes
    ----------
    x, y : float
        The numbers as given.
    unit : {"fraction", "m", "px"}
        Fractions of the scene's frame, metres, or pixels of the reference image.
    """

    x: float
    y: float
    unit: str = "fraction"

    def __str__(self) -> str:
        suffix = "" if self.unit == "fraction" else self.unit
        return f"{self.x:g}{suffix},{self.y:g}{suffix}"


def _quantity(text: str, what: str, whole: Any) -> tuple[float, str]:
    m = _QUANTITY.match(text)
    shown = ",".join(map(str, whole)) if not isinstance(whole, str) else whole
    if m is None:
        raise InputError(
            f"{what} {shown!r}: {text.strip()!r} is not a number, a number of metres (3.2m) "
            "or of pixels (120px)"
        )
    value = float(m[1])
    if not math.isfinite(value):
        raise InputError(f"{what} {shown!r}: {text.strip()!r} is not finite")
    return value, m[2] or "fraction"


def _scalar(v: Any) -> bool:
    if isinstance(v, str):
        return "," not in v
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


def parse_position(value: Any, what: str = "position") -> Position:
    """A :class:`Position` from ``"fx,fy"``, ``"3.2m,1.0m"``, ``"120px,300px"``, a pair of
    numbers (fractions) or of strings with a unit, or a :class:`Position`.

    Parameters
    ----------
    value : str, sequence of two items, or Position
        The point as typed.
    what : str
        What it is, for errors (``"--start"``, ``"robot 2's start"``).

    Raises
    ------
    InputError
        For anything else, two different units, a unit that is not m or px, or a fraction
        outside [0, 1].
    """
    if isinstance(value, Position):
        return value
    if isinstance(value, str):
        parts: list[Any] = value.split(",")
    elif isinstance(value, (Sequence, np.ndarray)) and not isinstance(value, bytes):
        parts = list(value)
    else:
        parts = []
    if len(parts) != 2 or not all(_scalar(p) for p in parts):
        raise InputError(
            f"{what} must be two numbers fx,fy (fractions of the scene) or two with a unit "
            f"(3.2m,1.0m), got {value!r}"
        )
    values, units = [], []
    for p in parts:
        if isinstance(p, str):
            v, unit = _quantity(p, what, value)
        else:
            v, unit = float(p), "fraction"
            if not math.isfinite(v):
                raise InputError(f"{what} must be finite, got {value!r}")
        values.append(v)
        units.append(unit)
    if units[0] != units[1]:
        raise InputError(
            f"{what}: both numbers need the same unit (3.2m,1.0m or 0.1,0.5), got {value!r}"
        )
    pos = Position(values[0], values[1], units[0])
    if pos.unit == "fraction" and not (0.0 <= pos.x <= 1.0 and 0.0 <= pos.y <= 1.0):
        raise InputError(
            f"{what}: {pos} are read as fractions of the scene's width and height, which lie "
            f"in [0, 1]; write {pos.x:g}m,{pos.y:g}m for metres"
        )
    return pos


def parse_positions(value: Any, what: str = "goals") -> list[Position]:
    """Several positions (goals visited in order): a list of what :func:`parse_position`
    takes, or one of them alone.

    Parameters
    ----------
    value : str, Position, or sequence
        One position, or a sequence of positions.
    what : str
        What they are, for errors.
    """
    if isinstance(value, (str, Position)):
        return [parse_position(value, what)]
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, Sequence) or len(value) == 0:
        raise InputError(f"{what} must be one position or a list of positions, got {value!r}")
    if len(value) == 2 and all(_scalar(v) for v in value):
        return [parse_position(value, what)]  # one pair
    return [parse_position(v, f"{what} {i + 1}") for i, v in enumerate(value)]


def to_metres(
    pos: Position,
    *,
    frame: tuple[np.ndarray, np.ndarray] | None,
    m_per_px: float | None,
    scene: str,
    what: str = "position",
) -> np.ndarray:
    """The point in metres (scene coordinates).

    Parameters
    ----------
    pos : Position
        The point as typed.
    frame : (origin, size) in metres, optional
        The scene's frame fractions refer to (None: the scene has none).
    m_per_px : float, optional
        Metres per pixel of the reference image (None: the scene has no image).
    scene : str
        The scene's name, for errors.
    what : str
        What the point is, for errors.
    """
    xy = np.array([pos.x, pos.y], dtype=float)
    if pos.unit == "m":
        return xy
    if pos.unit == "px":
        if m_per_px is None:
            raise InputError(f"{what} {pos}: scene {scene} has no image; give metres (3.2m,1.0m)")
        return xy * float(m_per_px)
    if frame is None:
        raise InputError(
            f"{what} {pos}: scene {scene} has no frame for fractions; give metres (3.2m,1.0m)"
        )
    origin, size = frame
    out: np.ndarray = np.asarray(origin, dtype=float) + xy * np.asarray(size, dtype=float)
    return out


def scene_frame(scene: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """(origin, size) in metres of the frame a scene's fractions refer to: the reference
    image (``scene.extent``, from the origin) or the recording's walkable box
    (``scene.meta["walkable_box"]``, ETH/UCY); None when the scene has neither.

    Parameters
    ----------
    scene : Scene
        The scene.
    """
    if scene.extent is not None:
        return np.zeros(2), np.asarray(scene.extent, dtype=float)
    box = scene.meta.get("walkable_box")
    if box is None:
        return None
    lo, hi = np.asarray(box, dtype=float)
    return lo, hi - lo


def scene_position(scene: Any, value: Any, what: str = "position") -> np.ndarray:
    """A position as typed (:func:`parse_position`) in metres on ``scene``: fractions of its
    frame (:func:`scene_frame`), metres, or pixels at its ``meta["m_per_px"]``.

    Parameters
    ----------
    scene : Scene
        The scene the position is on.
    value : str, sequence of two items, or Position
        The position as typed.
    what : str
        What it is, for errors.
    """
    return to_metres(
        parse_position(value, what),
        frame=scene_frame(scene),
        m_per_px=scene.meta.get("m_per_px"),
        scene=scene.name,
        what=what,
    )
