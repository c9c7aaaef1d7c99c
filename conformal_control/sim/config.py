"""Run parameters: defaults, parsing of ``KEY=VALUE``, conversion to SI, validation."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from ..data.scene import Scene
from ..data.units import PARAM_DIMENSIONS

__all__ = ["PARAMETERS", "ResolvedParams", "parse_value", "resolve_params", "to_scene_units"]

#: Every controller parameter: name -> (default, description). ``None`` defaults are
#: filled from the scene (``scene.defaults`` first, then the scene's own attributes).
#: Dimensional parameters are typed in the scene's units (see ``conformal_control.data.units``).
PARAMETERS: dict[str, tuple[Any, str]] = {
    "a": (None, "slope of alpha(h) = a h (1/time)"),
    "K_acc": (None, "velocity-tracking gain of u = -K_acc (v - v_QP) (1/time)"),
    "K_rep": (None, "repulsive gain of the APF barrier (length^2)"),
    "K_att": (None, "attractive gain of the reference v_ref = -K_att (X - X_goal) (1/time)"),
    "rho0": (None, "APF influence distance (length)"),
    "sensing_radius": (None, "sensor range, centre distance (length); default rho0"),
    "tau": (None, "sampling period of sensor, predictor and lambda update (time)"),
    "eta": (None, "learning rate of lambda (1/time)"),
    "epsilon": (None, "target average loss, in (-1/2, 1/2)"),
    "loss_scale": (None, "loss scale c in s(r) = arctan(r/c)/pi (1/time)"),
    "lambda_init": (0.0, "initial lambda (1/time)"),
    "lambda_min": (-math.inf, "clip lambda from below (1/time) against wind-up"),
    "lambda_max": (math.inf, "clip lambda from above (1/time)"),
    "convention": ("surface", "barrier distance: 'surface' (disc gap) or 'centre'"),
    "delta": (None, "barrier offset delta; default 1/2 (surface) or 1/(1+U(d_c)) (centre)"),
    "fallback": ("lambda_search", "on an infeasible QP: lambda_search | brake | hold"),
    "speed_sides": (16, "sides of the inscribed speed polygon (0 = box)"),
    "substeps": (4, "QP solves (control instants) per data frame"),
    "history": (None, "frames of history handed to the predictor; default 4 s of frames"),
    "v_max": (None, "robot speed bound (m/s)"),
    "barrier_margin": (0.0, "extra distance added to d_c in the barrier only (m): a robust CBF"),
    "robot_radius": (None, "robot radius (m)"),
    "agent_radius": (None, "pedestrian radius (m)"),
    "goal_radius": (None, "goal radius (m)"),
}


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
        raise ValueError(f"units must be 'scene' or 'si', got {units!r}")
    out = {}
    for k, v in params.items():
        if k in PARAM_DIMENSIONS and isinstance(v, (int, float)) and not isinstance(v, bool):
            v = v / scene.units.factor(k)
            if k == "tau" and abs(v - round(v)) < 1e-9:
                v = round(v)
        out[k] = v
    return out


def parse_value(text: str) -> Any:
    """Parse a ``--param`` value: int, float (inf too), bool, none, or string."""
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
        raise ValueError(f"parameter {name} must be a finite number {bound}, got {v!r}")


def resolve_params(scene: Scene, given: dict[str, Any]) -> ResolvedParams:
    """Merge defaults, scene defaults and user values; convert to SI; validate.

    Raises
    ------
    ValueError
        For an unknown parameter or a nonsensical value (negative tau or eta, ...).
    """
    unknown = sorted(set(given) - set(PARAMETERS))
    if unknown:
        raise ValueError(
            f"unknown parameter(s) {', '.join(unknown)}; known: {', '.join(PARAMETERS)}"
        )
    merged: dict[str, Any] = {k: d for k, (d, _) in PARAMETERS.items()}
    merged.update({k: v for k, v in scene.defaults.items() if k in PARAMETERS})
    for name in ("v_max", "robot_radius", "agent_radius", "goal_radius"):
        merged[name] = getattr(scene, name)
    if merged["history"] is None:
        merged["history"] = round(4.0 * scene.fps)
    merged.update(given)
    missing = [k for k, v in merged.items() if v is None and k not in ("sensing_radius", "delta")]
    if missing:
        raise ValueError(f"scene {scene.name} has no default for: {', '.join(missing)}")
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
    eps = si["epsilon"]
    if not (isinstance(eps, (int, float)) and -0.5 < eps < 0.5):
        raise ValueError(f"epsilon must lie in (-1/2, 1/2) (the loss's range), got {eps!r}")
    for name in ("substeps", "history"):
        v = merged[name]
        if not (isinstance(v, int) and v >= 1):
            raise ValueError(f"parameter {name} must be a positive integer, got {v!r}")
    if (
        not isinstance(merged["speed_sides"], int)
        or merged["speed_sides"] in (1, 2)
        or (merged["speed_sides"] < 0)
    ):
        raise ValueError(f"speed_sides must be 0 or an integer >= 3, got {merged['speed_sides']!r}")
    tau_frames_f = si["tau"] * scene.fps
    tau_frames = round(tau_frames_f)
    if tau_frames < 1 or abs(tau_frames - tau_frames_f) > 1e-6:
        raise ValueError(
            f"tau must be a positive whole number of frames (frame period {1 / scene.fps:g} s); "
            f"tau = {merged['tau']} {scene.units.time_name} is {tau_frames_f:g} frames"
        )
    for name in ("lambda_init", "lambda_min", "lambda_max"):
        v = si[name]
        if not isinstance(v, (int, float)) or math.isnan(v):
            raise ValueError(f"parameter {name} must be a number, got {v!r}")
    if si["lambda_min"] > si["lambda_max"]:
        raise ValueError("lambda_min must not exceed lambda_max")
    dims = {k: scene.units.unit_of(k) for k in PARAM_DIMENSIONS}
    return ResolvedParams(
        given=dict(given),
        scene_units={**merged, "_units": dims},
        si=si,
        tau_frames=tau_frames,
        history_frames=int(merged["history"]),
    )
