"""Run parameters: defaults, parsing of ``KEY=VALUE``, conversion to SI, validation.

A dimensional parameter is typed in the scene's units (SDD: pixels and frames, the
paper's; the built-in scene: metres and seconds) unless its value carries a unit suffix,
which is converted with the scene's own scale and frame rate:

=============  =====================================================================
dimension      accepted suffixes (examples)
=============  =====================================================================
length         ``m``, ``cm``, ``mm``, ``px`` (``rho0=18m``, ``rho0=400px``)
length^2       ``m^2``, ``px^2`` (``K_rep=0.1m^2``)
time           ``s``, ``ms``, ``frame``/``frames`` (``tau=0.4s``, ``tau=12frames``)
1/time         ``/s``, ``1/s``, ``Hz``, ``/frame``, ``1/frame`` (``eta=30/s``)
=============  =====================================================================

A bare number that is implausible in the unit it is read in (a length under 1 m or over
100 m, a sampling period over 10 s) raises a
:class:`~conformal_control.core.exceptions.SuspiciousValueWarning` that suggests the suffix.
"""

from __future__ import annotations

import difflib
import logging
import math
import re
import warnings
from dataclasses import dataclass, field
from typing import Any

from ..core.base import LAMBDA_PER
from ..core.exceptions import InputError, SuspiciousValueWarning
from ..core.spec import PARAM_DIMENSIONS, PARAMETERS, PLAUSIBLE_SI, parameter_info
from ..core.update_rules.base import check_epsilon
from ..data.scene import Scene

__all__ = [
    "PARAMETERS",
    "UNIT_SUFFIXES",
    "ResolvedParams",
    "check_names",
    "convert_units",
    "parse_value",
    "resolve_params",
    "suggest",
    "to_scene_units",
]


def to_scene_units(scene: Scene, params: dict[str, Any], units: str) -> dict[str, Any]:
    """Parameters typed in ``units`` ("scene" or "si"), expressed in the scene's units.

    Raises
    ------
    ValueError
        For a unit system other than "scene" or "si".
    """
    if units == "scene":
        return dict(params)
    if units != "si":
        raise InputError(f"units must be 'scene' or 'si', got {units!r}")
    out = {}
    for k, v in params.items():
        if k in PARAM_DIMENSIONS and isinstance(v, (int, float)) and not isinstance(v, bool):
            v = v / scene.units.factor(k)
            if k == "tau" and abs(v - round(v)) < 1e-9:
                v = round(v)
        out[k] = v
    return out


#: dimension (length exponent, time exponent) -> accepted suffixes
UNIT_SUFFIXES: dict[tuple[int, int], tuple[str, ...]] = {
    (1, 0): ("m", "cm", "mm", "px"),
    (2, 0): ("m^2", "m2", "px^2", "px2"),
    (0, 1): ("s", "ms", "frame", "frames"),
    (0, -1): ("/s", "1/s", "Hz", "/frame", "1/frame"),
}
_DIMENSION_NAMES = {(1, 0): "a length", (2, 0): "an area", (0, 1): "a time", (0, -1): "a rate"}
_QUANTITY = re.compile(
    r"^\s*(?P<num>[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|[+-]?inf)\s*(?P<unit>[^\d\s].*?)\s*$"
)


def suggest(name: str, known: list[str] | tuple[str, ...]) -> str:
    """``" did you mean 'x'?"`` for the closest known name, or ``""``."""
    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.6)
    return f" did you mean {close[0]!r}?" if close else ""


def _unit_si(scene: Scene, unit: str) -> tuple[tuple[int, int], float] | None:
    """(dimension, SI value of one ``unit``) on ``scene``; None for an unknown unit."""
    u = unit.strip()
    px = scene.units.length if scene.units.length_name == "px" else scene.meta.get("m_per_px")
    frame = 1.0 / scene.fps
    table: dict[str, tuple[tuple[int, int], float | None]] = {
        "m": ((1, 0), 1.0),
        "cm": ((1, 0), 0.01),
        "mm": ((1, 0), 0.001),
        "px": ((1, 0), px),
        "m^2": ((2, 0), 1.0),
        "m2": ((2, 0), 1.0),
        "px^2": ((2, 0), None if px is None else px * px),
        "px2": ((2, 0), None if px is None else px * px),
        "s": ((0, 1), 1.0),
        "ms": ((0, 1), 0.001),
        "frame": ((0, 1), frame),
        "frames": ((0, 1), frame),
        "/s": ((0, -1), 1.0),
        "1/s": ((0, -1), 1.0),
        "hz": ((0, -1), 1.0),
        "/frame": ((0, -1), 1.0 / frame),
        "1/frame": ((0, -1), 1.0 / frame),
    }
    hit = table.get(u) or table.get(u.lower())
    if hit is None:
        return None
    dim, factor = hit
    if factor is None:
        raise InputError(
            f"scene {scene.name} has no pixel scale, so 'px' cannot be converted; give the "
            "value in metres (e.g. rho0=5m)"
        )
    return dim, factor


def convert_units(scene: Scene, given: dict[str, Any]) -> tuple[dict[str, Any], list[str]]:
    """Values with a unit suffix converted to the scene's units; the others unchanged.

    Returns the converted parameters and one note per conversion (``"rho0=18m -> 392.3
    px"``). Warns (:class:`SuspiciousValueWarning`) about implausible bare numbers.

    Raises
    ------
    InputError
        For an unknown suffix, a suffix of the wrong dimension, or a suffix on a
        parameter without a dimension.
    """
    out: dict[str, Any] = {}
    notes: list[str] = []
    for key, value in given.items():
        if isinstance(value, str):
            m = _QUANTITY.match(value)
            if m is not None:
                number, unit = float(m["num"]), m["unit"]
                dim = PARAM_DIMENSIONS.get(key)
                if dim is None:
                    raise InputError(
                        f"parameter {key} has no unit, but {key}={value} gives one; "
                        f"write {key}={m['num']}"
                    )
                hit = _unit_si(scene, unit)
                suffixes = ", ".join(UNIT_SUFFIXES.get(dim, ()))
                if hit is None or hit[0] != dim:
                    what = "unknown unit" if hit is None else "wrong unit"
                    raise InputError(
                        f"{what} {unit!r} in {key}={value}: {key} is "
                        f"{_DIMENSION_NAMES.get(dim, 'a dimensional quantity')}, use one of "
                        f"{suffixes}"
                    )
                scene_value = number * hit[1] / scene.units.factor(key)
                if dim == (0, 1) and abs(scene_value - round(scene_value)) < 1e-6:
                    scene_value = round(scene_value)
                out[key] = scene_value
                notes.append(
                    f"{key}={value} -> {scene_value:g} {scene.units.unit_of(key)} on {scene.name}"
                )
                continue
        out[key] = value
        _check_plausible(scene, key, value)
    return out, notes


#: dimension -> the suffixes of each unit system (SI first), as a value is written
_SYSTEM_SUFFIXES: dict[tuple[int, int], tuple[str, ...]] = {
    (1, 0): ("m", "px"),
    (0, 1): ("s", "frames"),
    (0, -1): ("/s", "/frame"),
}


def _suffix(unit: str) -> str:
    """How a value in ``unit`` (``unit_of``'s name) is written: ``frame`` -> ``frames``,
    ``1/frame`` -> ``/frame``."""
    if unit == "frame":
        return "frames"
    return unit[1:] if unit.startswith("1/") else unit


def _check_plausible(scene: Scene, key: str, value: Any) -> None:
    """Warn when a bare number is implausible in the unit it is read in; suggest the
    suffix of the unit system in which it would be plausible (seconds / frames, 1/s /
    1/frame, metres / pixels), if there is one."""
    if key not in PLAUSIBLE_SI or isinstance(value, bool):
        return
    if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        return
    if scene.defaults.get(key) == value:  # the scene's own default (Table I's eta = 100)
        return
    lo, hi, si_unit = PLAUSIBLE_SI[key]
    si = value * scene.units.factor(key)
    if lo <= si <= hi:
        return
    unit = scene.units.unit_of(key)
    side = f"less than {lo:g} {si_unit}" if si < lo else f"more than {hi:g} {si_unit}"
    keep = f"{key}={value:g}{_suffix(unit)}"
    alt = ""
    for other in _SYSTEM_SUFFIXES.get(PARAM_DIMENSIONS[key], ()):
        if other == _suffix(unit):
            continue
        try:
            hit = _unit_si(scene, other)
        except InputError:  # no pixel scale on this scene
            continue
        if hit is None:
            continue
        other_si = value * hit[1]
        if lo <= other_si <= hi:
            meant = "1" + other if other.startswith("/") else other
            alt = f", or {key}={value:g}{other} if you meant {meant}" + (
                "" if other_si == value else f" ({other_si:.3g} {si_unit})"
            )
            break
    read = f"{value:g} {unit}" + ("" if unit == si_unit else f" = {si:.3g} {si_unit}")
    warnings.warn(
        SuspiciousValueWarning(
            f"{key}={value:g} is read in the scene's unit: {read} on {scene.name}, {side}; "
            f"write {keep} to confirm it{alt}"
        ),
        stacklevel=2,
    )


def _tau_message(scene: Scene, tau: Any, frames: float) -> str:
    """Why ``tau`` is not a whole number of frames, and the value probably meant."""
    unit = scene.units.time_name
    head = (
        f"tau must be a positive whole number of frames (frame period {1 / scene.fps:g} s on "
        f"{scene.name})"
    )
    if unit == "frame":
        text = f"{head}, not {tau:g}"
    else:
        text = f"{head}; tau = {tau:g} {unit} is {frames:g} frames"
    if unit == "frame" and isinstance(tau, (int, float)):
        as_seconds = tau * scene.fps  # the number read as seconds, in frames
        if as_seconds >= 1 and abs(as_seconds - round(as_seconds)) < 1e-6:
            return f"{text}; write tau={tau:g}s if you meant seconds ({round(as_seconds)} frames)"
    near = sorted({max(1, math.floor(frames)), max(1, math.ceil(frames))})
    options = " or ".join(f"tau={n / scene.fps:g}s ({n} frame{'s' if n > 1 else ''})" for n in near)
    return f"{text}; the nearest are {options}"


def parse_value(text: str) -> Any:
    """Parse a ``--param`` value: int, float (inf too), bool, none, or string (a value
    with a unit suffix such as ``18m`` stays a string; :func:`convert_units` reads it)."""
    t = text.strip()
    low = t.lower()
    if low in ("true", "false"):
        return low == "true"
    if low in ("none", "null"):
        return None
    try:
        return int(t)
    except ValueError:
        pass
    try:
        return float(t)
    except ValueError:
        return t


@dataclass
class ResolvedParams:
    """Parameters as given, as used (scene units) and in SI."""

    given: dict[str, Any]
    scene_units: dict[str, Any]
    si: dict[str, Any]
    tau_frames: int
    history_frames: int
    notes: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return {
            "given": self.given,
            "used": self.scene_units,
            "si": self.si,
            "tau_frames": self.tau_frames,
            "history_frames": self.history_frames,
        }


def _positive(si: dict[str, Any], name: str, allow_zero: bool = False) -> None:
    v = si[name]
    ok = isinstance(v, (int, float)) and math.isfinite(v) and (v >= 0 if allow_zero else v > 0)
    if not ok:
        bound = ">= 0" if allow_zero else "> 0"
        raise InputError(f"parameter {name} must be a finite number {bound}, got {v!r}")


#: parameters whose value is a string (every other one is numeric)
_TEXT_PARAMS = ("convention", "lambda_per", "edge")


def check_names(given: dict[str, Any]) -> None:
    """Raise :class:`InputError` (with a did-you-mean) for a name not in :data:`PARAMETERS`."""
    unknown = sorted(set(given) - set(PARAMETERS))
    if unknown:
        raise InputError(
            f"unknown parameter {unknown[0]!r};{suggest(unknown[0], list(PARAMETERS))} the "
            f"parameters are {', '.join(PARAMETERS)} (see `conformal-control params`)"
        )


def resolve_params(scene: Scene, given: dict[str, Any]) -> ResolvedParams:
    """Merge defaults, scene defaults and user values; convert to SI; validate.

    Raises
    ------
    ValueError
        For an unknown parameter or a nonsensical value (negative tau or eta, ...).
    """
    check_names(given)
    for key, value in given.items():
        if isinstance(value, bool):
            raise InputError(
                f"parameter {key} must be a number, got the boolean {str(value).lower()}"
            )
    converted, notes = convert_units(scene, given)
    for text in notes:  # (shown by the command line with -v)
        logging.getLogger(__name__).info("unit conversion: %s", text)
    for key, value in converted.items():
        if key not in _TEXT_PARAMS and isinstance(value, str):
            raise InputError(f"parameter {key} must be a number, got {value!r}")
    merged: dict[str, Any] = {k: d for k, (d, _) in PARAMETERS.items()}
    merged.update({k: v for k, v in scene.defaults.items() if k in PARAMETERS})
    for name in ("v_max", "robot_radius", "agent_radius", "goal_radius"):
        merged[name] = getattr(scene, name)
    if merged["history"] is None:
        merged["history"] = round(4.0 * scene.fps)
    merged.update(converted)
    missing = [k for k, v in merged.items() if v is None and k not in ("sensing_radius", "delta")]
    if missing:
        raise InputError(f"scene {scene.name} has no default for: {', '.join(missing)}")
    if merged["sensing_radius"] is None:
        merged["sensing_radius"] = merged["rho0"]
    si = scene.units.to_si(merged)
    for name in (
        "a",
        "K_acc",
        "K_rep",
        "K_att",
        "rho0",
        "sensing_radius",
        "tau",
        "loss_scale",
        "v_max",
        "robot_radius",
        "agent_radius",
        "goal_radius",
    ):
        _positive(si, name)
    _positive(si, "eta", allow_zero=True)
    _positive(si, "barrier_margin", allow_zero=True)
    _positive(si, "escape_margin", allow_zero=True)
    check_epsilon(si["epsilon"])
    # whole-number parameters in their table's range, before anything is allocated with
    # them (substeps=1e8 asked for 95 GiB; speed_sides=1e8 ran for minutes)
    for name in ("substeps", "history"):
        v = merged[name]
        info = parameter_info(name)
        if not (isinstance(v, int) and info.low <= v <= info.high):
            raise InputError(f"parameter {name} must be an integer in {info.range_text}, got {v!r}")
    sides, top = merged["speed_sides"], int(parameter_info("speed_sides").high)
    if not isinstance(sides, int) or sides in (1, 2) or not 0 <= sides <= top:
        raise InputError(f"speed_sides must be 0 or an integer from 3 to {top}, got {sides!r}")
    tau_frames_f = si["tau"] * scene.fps
    tau_frames = round(tau_frames_f)
    if tau_frames < 1 or abs(tau_frames - tau_frames_f) > 1e-6:
        raise InputError(_tau_message(scene, merged["tau"], tau_frames_f))
    for name in ("lambda_init", "lambda_min", "lambda_max"):
        v = si[name]
        if not isinstance(v, (int, float)) or math.isnan(v):
            raise InputError(f"parameter {name} must be a number, got {v!r}")
    if not math.isfinite(si["lambda_init"]):
        raise InputError(f"parameter lambda_init must be finite, got {si['lambda_init']!r}")
    if si["lambda_min"] == math.inf or si["lambda_max"] == -math.inf:
        bad = "lambda_min" if si["lambda_min"] == math.inf else "lambda_max"
        raise InputError(
            f"parameter {bad} must be finite or the open end ({'-' if bad == 'lambda_min' else ''}"
            f"inf), got {si[bad]!r}: lambda would have no finite value left"
        )
    if si["lambda_min"] > si["lambda_max"]:
        raise InputError("lambda_min must not exceed lambda_max")
    delta = si["delta"]
    if delta is not None and not (
        isinstance(delta, (int, float)) and math.isfinite(delta) and 0 < delta < 1
    ):
        raise InputError(
            f"parameter delta must be a number in (0, 1) (the barrier 1/(1+U) - delta is "
            f"then positive far from every agent), got {delta!r}"
        )
    for name in _TEXT_PARAMS:
        if not isinstance(merged[name], str):
            raise InputError(f"parameter {name} must be a name, got {merged[name]!r}")
    if merged["edge"] not in ("escape", "paper"):
        raise InputError(f"parameter edge must be 'escape' or 'paper', got {merged['edge']!r}")
    if merged["lambda_per"] not in LAMBDA_PER:
        raise InputError(
            f"parameter lambda_per must be one of {', '.join(LAMBDA_PER)}, "
            f"got {merged['lambda_per']!r}"
        )
    q = merged["lambda_prior"]
    if not (isinstance(q, (int, float)) and 0.0 <= q <= 1.0):
        raise InputError(f"parameter lambda_prior must be a quantile in [0, 1], got {q!r}")
    r = merged["lambda_floor_row"]
    if not (isinstance(r, (int, float)) and 0.0 <= r <= 1.0):
        raise InputError(f"parameter lambda_floor_row must be a share in [0, 1], got {r!r}")
    if r and merged["lambda_per"] != "agent":
        raise InputError(
            f"parameter lambda_floor_row={r!r} needs lambda_per='agent' (a floor per agent's row)"
        )
    step, limit = si["lambda_floor_step"], si["lambda_floor_limit"]
    if not (isinstance(step, (int, float)) and math.isfinite(step) and step >= 0.0):
        raise InputError(f"parameter lambda_floor_step must be a finite rate >= 0, got {step!r}")
    if not isinstance(limit, (int, float)) or math.isnan(limit) or limit == math.inf:
        raise InputError(f"parameter lambda_floor_limit must be a number or -inf, got {limit!r}")
    if step and merged["lambda_per"] != "agent":
        raise InputError(
            f"parameter lambda_floor_step={step!r} needs lambda_per='agent' (a floor per agent)"
        )
    if step and limit > si["lambda_min"]:
        raise InputError(
            f"parameter lambda_floor_limit ({limit!r}) must not exceed lambda_min "
            f"({si['lambda_min']!r}): the floor only steps down from lambda_min"
        )
    dims = {k: scene.units.unit_of(k) for k in PARAM_DIMENSIONS}
    return ResolvedParams(
        given=dict(given),
        scene_units={**merged, "_units": dims},
        si=si,
        tau_frames=tau_frames,
        history_frames=int(merged["history"]),
        notes=notes,
    )
