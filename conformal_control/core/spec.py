"""The run specification: the one table of controller parameters (this module) and the
:class:`RunSpec` every entry point builds or takes.

:class:`Parameters` is the table: one field per controller parameter, each carrying its
default, its dimension (``length^p time^q``: how it converts between a scene's units and
SI), the range it must lie in and its documentation. Everything else that lists
parameters is derived from it: :data:`PARAMETERS` (name -> (default, doc), what
``conformal-control params`` prints), :data:`PARAM_DIMENSIONS` (what
:class:`~conformal_control.data.units.UnitSystem` converts) and :data:`PLAUSIBLE_SI`
(the SI range outside which a bare number is reported as suspicious).

This module imports nothing of the package but the exceptions and the generic core
(:mod:`~conformal_control.core.base`), so every floor of the house can read the table and the
specification.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass, field
from typing import Any

from .base import expand_settings
from .exceptions import ConformalControlDeprecationWarning, InputError

__all__ = [
    "LAMBDA_SAFE_AUTO",
    "LAMBDA_SAFE_AUTO_SOURCE",
    "OPTION_FIELDS",
    "PARAMETERS",
    "PARAM_DIMENSIONS",
    "PLAUSIBLE_SI",
    "ROLE_FIELDS",
    "RUN_VALUES",
    "ParamInfo",
    "Parameters",
    "RunContext",
    "RunSpec",
    "parameter_info",
]


@dataclass(frozen=True)
class ParamInfo:
    """What the table knows about one parameter.

    Attributes
    ----------
    doc : str
        One line, as ``conformal-control params`` prints it.
    dimension : (int, int) or None
        Exponents of length and time (``(0, -1)``: a rate); None for a parameter that is
        not converted between unit systems (dimensionless, or always SI such as ``v_max``).
    kind : {"float", "int", "text"}
        The value's type.
    low, high : float
        The range the value (in SI) must lie in.
    closed : (bool, bool)
        Whether ``low`` and ``high`` belong to the range.
    plausible : (float, float, str) or None
        SI range and unit outside which a bare number (no unit suffix) is reported as
        suspicious (probably typed in the other unit system: seconds for frames, 1/s for
        1/frame, metres for pixels). Every scene's defaults and the paper's values lie
        inside, but Table I's eta = 100/frame (3000/s on gates_1), which is gates_1's
        default (a scene's own default is never reported).
    """

    doc: str
    dimension: tuple[int, int] | None = None
    kind: str = "float"
    low: float = -math.inf
    high: float = math.inf
    closed: tuple[bool, bool] = (True, True)
    plausible: tuple[float, float, str] | None = None

    @property
    def range_text(self) -> str:
        """The range as a reader writes it, e.g. ``(0, inf)`` or ``[1, inf)``."""
        lo = "[" if self.closed[0] and math.isfinite(self.low) else "("
        hi = "]" if self.closed[1] and math.isfinite(self.high) else ")"
        return f"{lo}{self.low:g}, {self.high:g}{hi}"


def _p(default: Any, doc: str, **info: Any) -> Any:
    """A table entry: ``default`` (None: from the scene) and its :class:`ParamInfo`."""
    return field(default=default, metadata={"info": ParamInfo(doc, **info)})


_RATE = (0, -1)
_LENGTH = (1, 0)
_POSITIVE: dict[str, Any] = {"low": 0.0, "closed": (False, True)}
_NON_NEGATIVE: dict[str, Any] = {"low": 0.0}


@dataclass(frozen=True)
class Parameters:
    """Every controller parameter with its default (None: the scene's default).

    Dimensional parameters are typed in the scene's units (SDD: pixels and frames, the
    paper's) unless a run says ``units="si"``; each field's ``metadata["info"]`` is its
    :class:`ParamInfo` (unit, range, doc).
    """

    a: float | None = _p(
        None,
        "slope of alpha(h) = a h (1/time)",
        dimension=_RATE,
        plausible=(0.0, 1000.0, "1/s"),
        **_POSITIVE,
    )
    K_acc: float | None = _p(
        None,
        "velocity-tracking gain of u = -K_acc (v - v_QP) (1/time)",
        dimension=_RATE,
        plausible=(0.0, 200.0, "1/s"),
        **_POSITIVE,
    )
    K_rep: float | None = _p(
        None, "repulsive gain of the APF barrier (length^2)", dimension=(2, 0), **_POSITIVE
    )
    K_att: float | None = _p(
        None,
        "attractive gain of the reference v_ref = -K_att (X - X_goal) (1/time)",
        dimension=_RATE,
        plausible=(0.0, 100.0, "1/s"),
        **_POSITIVE,
    )
    rho0: float | None = _p(
        None,
        "APF influence distance (length)",
        dimension=_LENGTH,
        plausible=(1.0, 100.0, "m"),
        **_POSITIVE,
    )
    sensing_radius: float | None = _p(
        None,
        "sensor range, centre distance (length); default rho0",
        dimension=_LENGTH,
        plausible=(1.0, 100.0, "m"),
        **_POSITIVE,
    )
    tau: float | None = _p(
        None,
        "sampling period of sensor, predictor and lambda update (time)",
        dimension=(0, 1),
        plausible=(0.0, 2.0, "s"),
        **_POSITIVE,
    )
    eta: float | None = _p(
        None,
        "learning rate of lambda (1/time)",
        dimension=_RATE,
        plausible=(0.0, 100.0, "1/s"),
        **_NON_NEGATIVE,
    )
    epsilon: float | None = _p(
        None,
        "target average loss, in (-1/2, 1/2)",
        low=-0.5,
        high=0.5,
        closed=(False, False),
    )
    loss_scale: float | None = _p(
        None,
        "loss scale c in s(r) = arctan(r/c)/pi (1/time)",
        dimension=_RATE,
        plausible=(0.0, 1000.0, "1/s"),
        **_POSITIVE,
    )
    lambda_init: float = _p(0.0, "initial lambda (1/time)", dimension=_RATE)
    lambda_min: float = _p(
        -math.inf, "clip lambda from below (1/time) against wind-up", dimension=_RATE
    )
    lambda_max: float = _p(math.inf, "clip lambda from above (1/time)", dimension=_RATE)
    lambda_per: str = _p(
        "run",
        "'run': one lambda for the run; 'agent': one per agent, each learned from its own loss",
        kind="text",
    )
    lambda_prior: float = _p(
        0.5,
        "per agent: quantile of the current lambdas a new agent starts at, in [0, 1]",
        low=0.0,
        high=1.0,
    )
    lambda_floor_row: float = _p(
        0.0,
        "per agent: share in [0, 1] of each agent's own row feasibility floor that may "
        "replace lambda_min for it (0: off)",
        low=0.0,
        high=1.0,
    )
    lambda_floor_step: float = _p(
        0.0,
        "per agent: how far an agent's own floor steps down (1/time) at an update whose "
        "lambda sat at it while its loss exceeded epsilon (0: off)",
        dimension=_RATE,
        **_NON_NEGATIVE,
    )
    lambda_floor_limit: float = _p(
        -math.inf,
        "per agent: the lowest floor lambda_floor_step reaches (1/time)",
        dimension=_RATE,
    )
    convention: str = _p(
        "surface", "barrier distance: 'surface' (disc gap) or 'centre'", kind="text"
    )
    edge: str = _p(
        "escape",
        "edge rule: 'escape' (never close in on an agent already within the collision "
        "distance; the CBF's lambda floored at 0.8 x -a h_max unless lambda_min is set) or "
        "'paper' (Algorithm 1 as published)",
        kind="text",
    )
    escape_margin: float = _p(
        0.1,
        "edge rule: distance beyond the collision distance its push aims at (m)",
        **_NON_NEGATIVE,
    )
    delta: float | None = _p(
        None,
        "barrier offset delta; default 1/2 (surface) or 1/(1+U(d_c)) (centre)",
        low=0.0,
        high=1.0,
        closed=(False, False),
    )
    speed_sides: int = _p(
        16,
        "sides of the inscribed speed polygon (0 = box; else 3 to 1024)",
        kind="int",
        low=0.0,
        high=1024.0,
    )
    substeps: int = _p(
        4, "QP solves (control instants) per data frame (1 to 100)", kind="int", low=1.0, high=100.0
    )
    history: int | None = _p(
        None,
        "frames of history handed to the predictor; default 4 s of frames (at most 100000)",
        kind="int",
        low=1.0,
        high=100_000.0,
    )
    v_max: float | None = _p(None, "robot speed bound (m/s)", **_POSITIVE)
    barrier_margin: float = _p(
        0.0,
        "extra distance added to d_c in the barrier only (m): a robust CBF",
        **_NON_NEGATIVE,
    )
    robot_radius: float | None = _p(None, "robot radius (m)", **_POSITIVE)
    agent_radius: float | None = _p(None, "pedestrian radius (m)", **_POSITIVE)
    goal_radius: float | None = _p(None, "goal radius (m)", **_POSITIVE)

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """Every parameter name, in the table's order."""
        return tuple(f.name for f in dataclasses.fields(cls))


def parameter_info(name: str) -> ParamInfo:
    """The :class:`ParamInfo` of parameter ``name`` (KeyError for an unknown name)."""
    return _INFO[name]


_INFO: dict[str, ParamInfo] = {f.name: f.metadata["info"] for f in dataclasses.fields(Parameters)}

#: name -> (default, description): ``None`` defaults are filled from the scene
#: (``scene.defaults`` first, then the scene's own attributes).
PARAMETERS: dict[str, tuple[Any, str]] = {
    f.name: (f.default, f.metadata["info"].doc) for f in dataclasses.fields(Parameters)
}

#: parameter -> (length exponent, time exponent); parameters not listed are SI already.
PARAM_DIMENSIONS: dict[str, tuple[int, int]] = {
    name: info.dimension for name, info in _INFO.items() if info.dimension is not None
}

#: SI range (and its unit) outside which a bare (suffix-less) value is reported as suspicious.
PLAUSIBLE_SI: dict[str, tuple[float, float, str]] = {
    name: info.plausible for name, info in _INFO.items() if info.plausible is not None
}


# ------------------------------------------------------------------------------ RunSpec
#: A role of a run: a registered name, an instance (used as given), ``(name, params)``,
#: or None (the flagship's default).
RoleValue = Any

#: The roles of a run, in the order they are reported: the registry's roles
#: (:data:`conformal_control.core.registry.ROLES`), by the same names.
ROLE_FIELDS: tuple[str, ...] = (
    "predictor",
    "barrier",
    "safety_filter",
    "fallback",
    "reference",
    "dynamics",
    "loss",
    "rule",
    "family",
    "crowd",
)
#: ``lambda_safe="auto"``: derived when the run is built (the CBF gap loss; see
#: :func:`conformal_control.families.cbf.safe_lambda.derive_lambda_safe`).
LAMBDA_SAFE_AUTO = "auto"
#: The ``lambda_safe_source`` of ``lambda_safe="auto"`` when none is given.
LAMBDA_SAFE_AUTO_SOURCE = (
    "derived: CBF gap bound (robot within its speed set, pedestrians true and predicted "
    "within the assumed speed bound)"
)
#: Options of a run (not controller parameters, not roles).
OPTION_FIELDS: tuple[str, ...] = (
    "units",
    "learn",
    "seed",
    "max_frames",
    "lambda_safe",
    "lambda_safe_source",
    "record_animation",
    "engine",
    "start_m",
    "goals_m",
)
_ROLE_DEFAULTS: dict[str, Any] = {
    "predictor": "constant_velocity",
    "rule": "fixed_eta",
    "crowd": "replay",
}
_OPTION_TYPES: dict[str, tuple[type, ...]] = {
    "units": (str,),
    "learn": (bool,),
    "seed": (int,),
    "max_frames": (int, type(None)),
    "lambda_safe": (int, float, str, type(None)),
    "lambda_safe_source": (str, type(None)),
    "record_animation": (bool,),
    "engine": (str,),
}


#: How config.json writes infinite parameter values (JSON has no infinity).
_INFINITE_TEXT = frozenset({"inf", "-inf", "Infinity", "-Infinity"})


def _spec_error(message: str) -> Exception:
    return InputError(message)


def _role_parts(name: str, value: RoleValue) -> tuple[Any, dict[str, Any]]:
    """``(name or instance or None, params)`` of a role value, type-checked."""
    if isinstance(value, tuple):
        if len(value) != 2 or not isinstance(value[0], str) or not isinstance(value[1], dict):
            raise _spec_error(f"role {name} as a pair must be (name, params dict), got {value!r}")
        return value[0], dict(value[1])
    if isinstance(value, list) and len(value) == 2 and isinstance(value[0], str):
        if not isinstance(value[1], dict):
            raise _spec_error(f"role {name} params must be a mapping, got {value[1]!r}")
        return value[0], dict(value[1])
    if isinstance(value, dict):  # the serialised form {"name": ..., "params": {...}}
        unknown = set(value) - {"name", "params"}
        if unknown or not isinstance(value.get("name"), str):
            raise _spec_error(
                f"role {name} as a mapping must be {{'name': str, 'params': {{...}}}}, "
                f"got {value!r}"
            )
        params = value.get("params") or {}
        if not isinstance(params, dict):
            raise _spec_error(f"role {name} params must be a mapping, got {params!r}")
        return value["name"], dict(params)
    if value is None or isinstance(value, str):
        return value, {}
    if isinstance(value, (bool, numbers.Number, bytes, list, set, frozenset)):
        raise _spec_error(
            f"role {name} must be a registered name, (name, params) or an instance, got "
            f"{_short(value)}"
        )
    return value, {}  # an instance: checked against the role's base class when built


def _short(value: Any) -> str:
    """``repr(value)``, cut to a length a one-line error can show."""
    import reprlib

    r = reprlib.Repr()
    r.maxstring = r.maxother = 60
    return r.repr(value)


def _check_stored_param(where: str, name: str, value: Any) -> None:
    """A controller parameter read from a file: a finite number (lambda_min may be -inf,
    lambda_max +inf), a short text with a unit (``"18m"``) or None (the scene's default)."""
    if value is None:
        return
    if isinstance(value, bool) or not isinstance(value, (numbers.Real, str)):
        raise _spec_error(f"{where}: parameter {name} must be a number, got {_short(value)}")
    if isinstance(value, str):
        if len(value) > 64:
            raise _spec_error(f"{where}: parameter {name} must be a number, got {_short(value)}")
        return
    v = float(value)
    if math.isnan(v) or (
        math.isinf(v)
        and not (name == "lambda_min" and v < 0)
        and not (name == "lambda_max" and v > 0)
    ):
        raise _spec_error(f"{where}: parameter {name} must be finite, got {value!r}")


#: The most robots one run drives.
MAX_ROBOTS = 20

#: The default near horizon (s) of a planning robot's lines with its peers
#: (:class:`Robots` ``peer_horizon``; chosen on the multi-robot benchmark, docs/multi-robot.md).
PEER_HORIZON_S = 1.2

#: The default distance (m) a reciprocal CBF robot's floor rows keep beyond the robots'
#: collision distance (:class:`Robots` ``floor_margin``; chosen on the multi-robot
#: benchmark, docs/multi-robot.md).
FLOOR_MARGIN_M = 0.1

#: The default choice of the reciprocal CBF robots' floor cores (:class:`Robots`
#: ``floor_core``; chosen by people first on the multi-robot benchmark,
#: docs/multi-robot.md).
FLOOR_CORE_DEFAULT = "always"

#: The choices of the robots section's text settings (:class:`Robots`).
ROBOT_CHOICES: dict[str, tuple[str, ...]] = {
    "layout": ("scene", "antipodal"),
    "sensor_history": ("tracked", "observed"),
    "reciprocity": ("reciprocal", "none"),
    "information": ("position", "velocity", "plan"),
    "lambda_scope": ("pedestrians", "robots", "both"),
    "hard_rows": ("level", "last"),
    "coordination": ("none", "yield"),
    "priority": ("pedestrians", "robots"),
    "floor_core": ("always", "inside", "calm", "ahead", "none"),
}

#: The settings of a run's robots section (:class:`Robots`).
ROBOT_FIELDS: tuple[str, ...] = (
    "robots",
    "starts",
    "goals",
    "layout",
    "radius",
    "center",
    "sensor_history",
    "reciprocity",
    "information",
    "lambda_scope",
    "weights",
    "ignoring",
    "sidestep",
    "hard_rows",
    "peer_horizon",
    "coordination",
    "priority",
    "floor_margin",
    "floor_core",
)


def _is_int(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _is_real(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _real_list(value: Any) -> list[float] | None:
    """``value`` as a list of finite floats, or None when it is not one."""
    if isinstance(value, (str, bytes, dict)) or not hasattr(value, "__iter__"):
        return None
    items = list(value)
    if not all(_is_real(v) and math.isfinite(v) for v in items):
        return None
    return [float(v) for v in items]


@dataclass(frozen=True)
class Robots:
    """Several robots in one crowd (each its own controller, no communication).

    Parameters
    ----------
    robots : int, optional
        Number of robots (1 to :data:`MAX_ROBOTS`), placed by ``layout``; or give
        ``starts`` and ``goals``.
    starts, goals : lists, optional
        Explicit tasks (m): one start ``[x, y]`` and one list of goals per robot.
    layout : {"scene", "antipodal"}
        ``scene``: robot 0 does the scene's task, robot i the same task rotated by
        2 pi i / M; ``antipodal``: on a circle of ``radius`` about ``center``.
    radius : float, optional
    center : [x, y], optional
    sensor_history : {"tracked", "observed"}
        Histories handed to each robot's predictor.
    reciprocity : {"reciprocal", "none"}
        Robots share each pair's constraint, or predict each other like pedestrians.
    information : {"position", "velocity", "plan"}
        What reciprocal robots know of each other (``"plan"``: they broadcast commands).
    lambda_scope : {"pedestrians", "robots", "both"}, optional
        The rows lambda is the slack of; None (default): ``"pedestrians"`` with
        reciprocity, ``"both"`` without (every row is a prediction then), see
        :attr:`scope`.
    weights : sequence of float, optional
        The fleet's share weights (robot i's share of a pair: ``w_i / (w_i + w_j)``).
    ignoring : sequence of int
        Robots that take no other robot into account (a robot that does not comply).
    sidestep : float
        Angle (rad, 0 to pi/2) a reciprocal robot held back by another turns its nominal
        velocity by.
    hard_rows : {"last", "level"}
        How the lambda search treats the rows lambda is not the slack of.
    peer_horizon : float, optional
        Planning families (MPC): how far ahead (s) a robot's plan keeps to the lines it
        shares with the other robots (default :data:`PEER_HORIZON_S`); None: the whole
        plan.
    coordination : {"none", "yield"}
        ``"yield"`` (needs ``information="plan"``): a robot whose rows about the other
        robots gave way broadcasts it, and its partners take the whole of each pair's
        constraint at the next instant.
    priority : {"pedestrians", "robots"}
        The rows kept longest when not every row can be met: ``"pedestrians"`` (default:
        the robot rows give way first) or ``"robots"`` (the pedestrians' lambda is raised
        first, the robot rows as ``hard_rows`` says).
    floor_margin : float
        CBF family, ``priority="pedestrians"``: how far (m, finite, >= 0) beyond the
        robots' collision distance the floor rows aim (the rows kept after the robots'
        barrier rows gave way; default :data:`FLOOR_MARGIN_M`); 0: the collision
        distance itself.
    floor_core : {"always", "inside", "calm", "ahead", "none"}
        CBF family, ``priority="pedestrians"``: which floor rows keep their cores (half
        the margin beyond the collision distance) before the pedestrians' rows give way:
        ``"always"`` every pair's, ``"inside"`` only the pairs already closer than the
        collision distance, ``"calm"`` only the pairs with no pedestrian inside its
        collision distance of either robot of the pair, ``"ahead"`` only the pairs with
        none inside nor predicted inside within a look-ahead (1 s) and those within the
        floor distance, ``"none"`` no pair's (the floor rows give way entirely first).

    Raises
    ------
    InputError
        For a setting of the wrong type or out of range (one line naming it). What
        depends on the number of robots (``ignoring``'s indices, the number of
        ``weights``) and the tasks themselves are checked when the run starts.
    """

    robots: int | None = None
    starts: Any = None
    goals: Any = None
    layout: str = "scene"
    radius: float | None = None
    center: Any = None
    sensor_history: str = "tracked"
    reciprocity: str = "reciprocal"
    information: str = "plan"
    lambda_scope: str | None = None
    weights: Any = None
    ignoring: Any = ()
    sidestep: float = 0.3
    hard_rows: str = "last"
    peer_horizon: float | None = PEER_HORIZON_S
    coordination: str = "none"
    priority: str = "pedestrians"
    floor_margin: float = FLOOR_MARGIN_M
    floor_core: str = FLOOR_CORE_DEFAULT

    def __post_init__(self) -> None:
        n = self.robots
        if n is not None and (not _is_int(n) or not 1 <= n <= MAX_ROBOTS):
            raise _spec_error(f"robots must be an integer from 1 to {MAX_ROBOTS}, got {n!r}")
        for name, choices in ROBOT_CHOICES.items():
            value = getattr(self, name)
            if not (value is None and name == "lambda_scope") and value not in choices:
                raise _spec_error(
                    f"robots {name} must be one of {', '.join(choices)}, got {value!r}"
                )
        r = self.radius
        if r is not None and not (_is_real(r) and math.isfinite(r) and r > 0):
            raise _spec_error(f"robots radius must be a finite number > 0 (m), got {r!r}")
        c = self.center
        if c is not None:
            xy = _real_list(c)
            if xy is None or len(xy) != 2:
                raise _spec_error(f"robots center must be two finite numbers [x, y] (m), got {c!r}")
            object.__setattr__(self, "center", tuple(xy))
        w = self.weights
        if w is not None:
            ws = _real_list(w)
            if ws is None or not ws or min(ws) <= 0:
                raise _spec_error(f"robots weights must be a list of finite numbers > 0, got {w!r}")
            object.__setattr__(self, "weights", tuple(ws))
        ig = self.ignoring
        if isinstance(ig, (str, bytes, dict)) or not hasattr(ig, "__iter__"):
            raise _spec_error(f"robots ignoring must be a list of robot indices, got {ig!r}")
        ig = list(ig)
        if not all(_is_int(i) and i >= 0 for i in ig):
            raise _spec_error(f"robots ignoring must be a list of robot indices, got {ig!r}")
        object.__setattr__(self, "ignoring", tuple(int(i) for i in ig))
        k = self.sidestep
        if not (_is_real(k) and 0.0 <= k <= math.pi / 2):
            raise _spec_error(f"robots sidestep must be an angle in [0, pi/2] (rad), got {k!r}")
        p = self.peer_horizon
        if p is not None and not (_is_real(p) and math.isfinite(p) and p > 0):
            raise _spec_error(f"robots peer_horizon must be a duration > 0 (s), got {p!r}")
        f = self.floor_margin
        if not (_is_real(f) and math.isfinite(f) and f >= 0):
            raise _spec_error(f"robots floor_margin must be a finite distance >= 0 (m), got {f!r}")

    @property
    def scope(self) -> str:
        """The rows lambda is the slack of: :attr:`lambda_scope`, or when None
        ``"pedestrians"`` with reciprocity and ``"both"`` without."""
        if self.lambda_scope is not None:
            return self.lambda_scope
        return "both" if self.reciprocity == "none" else "pedestrians"

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (arrays as lists)."""
        out = {}
        for name in ROBOT_FIELDS:
            v = getattr(self, name)
            out[name] = v.tolist() if hasattr(v, "tolist") else v
        return out


@dataclass(frozen=True)
class RunSpec:
    """One run of the flagship, fully specified: parameters, roles, crowd, robots, options.

    Every entry point builds one (the CLI from its flags, :func:`conformal_control.run`
    from its arguments, sweeps from a run configuration, the benchmark from a method and a
    scenario) and hands it to the same builder and engines; ``config.json`` holds
    :meth:`as_dict`, and :meth:`from_dict` reads it back (type-checked).

    Deep parameters (scikit-learn style): ``spec.get_params()`` flattens everything,
    ``predictor__window`` for a role's parameter and ``epsilon`` for a controller
    parameter; ``spec.set_params(predictor__window=3, epsilon=-0.1)`` returns the changed
    copy.

    Parameters
    ----------
    params : dict
        Controller parameters (:class:`Parameters`) overriding the scene's defaults, in
        the unit system ``units``; a string value may carry a unit suffix (``"18m"``).
    predictor, barrier, safety_filter, fallback, reference, dynamics, loss, rule, family, crowd
        Each role as a registered name, an instance (used as given, SI units),
        ``(name, params)``, or None for the flagship's default: the registry's roles,
        by the same names. The ``rule``'s parameters are in ``units``; the ``crowd`` is
        also ``"replay"`` (the recording) or ``"mixed"``.
    units : {"scene", "si"}
        Unit system of ``params`` and of the rule's parameters.
    learn : bool
        False keeps lambda at ``lambda_init`` (the noLearn baseline).
    seed : int
        Seed of the built-in scene, of reactive crowds and of plugins with a
        ``random_state``.
    max_frames : int, optional
        Limit on simulated frames.
    lambda_safe : float or "auto", optional
        lambda known or estimated to keep the robot safe (in ``units``); ``"auto"``: derived
        at build time for the CBF gap loss from the run's constraint, loss scale, epsilon
        and speed bounds
        (:func:`~conformal_control.families.cbf.safe_lambda.derive_lambda_safe`).
    lambda_safe_source : str, optional
        Where ``lambda_safe`` came from.
    record_animation : bool
        Keep the compact record ``conformal-control animate`` renders.
    engine : {"auto", "loop", "batch"}
        The backend (:mod:`conformal_control.runs.engines`).
    start_m : (x, y), optional
        The robot's start in metres, replacing the scene's (:meth:`on_scene`); None: the
        scene's own.
    goals_m : sequence of (x, y), optional
        The goals visited in order, in metres (one ``(x, y)`` for a single goal); None: the
        scene's own.
    robots : Robots, optional
        Several robots in the crowd (:func:`conformal_control.runs.fleet.run_multi`).

    """

    params: dict[str, Any] = field(default_factory=dict)
    predictor: RoleValue = "constant_velocity"
    barrier: RoleValue = None
    safety_filter: RoleValue = None
    fallback: RoleValue = None
    reference: RoleValue = None
    dynamics: RoleValue = None
    loss: RoleValue = None
    rule: RoleValue = "fixed_eta"
    family: RoleValue = None
    crowd: RoleValue = "replay"
    units: str = "scene"
    learn: bool = True
    seed: int = 0
    max_frames: int | None = None
    lambda_safe: float | str | None = None
    lambda_safe_source: str | None = None
    record_animation: bool = True
    engine: str = "auto"
    start_m: Any = None
    goals_m: Any = None
    robots: Robots | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.params, dict):
            raise _spec_error(f"params must be a mapping, got {self.params!r}")
        self._fallback_one_way()
        unknown = sorted(set(self.params) - set(PARAMETERS))
        if unknown:
            import difflib

            close = difflib.get_close_matches(unknown[0], list(PARAMETERS), n=1, cutoff=0.6)
            hint = f" did you mean {close[0]!r}?" if close else ""
            raise _spec_error(
                f"unknown parameter {unknown[0]!r};{hint} the parameters are "
                f"{', '.join(PARAMETERS)} (see `conformal-control params`)"
            )
        for name, types in _OPTION_TYPES.items():
            value = getattr(self, name)
            if not isinstance(value, types) or (isinstance(value, bool) and bool not in types):
                what = " or ".join(t.__name__ for t in types).replace("NoneType", "None")
                raise _spec_error(f"{name} must be {what}, got {value!r}")
        if self.units not in ("scene", "si"):
            raise _spec_error(f"units must be 'scene' or 'si', got {self.units!r}")
        if self.engine not in ("auto", "loop", "batch"):
            raise _spec_error(f"engine must be 'auto', 'loop' or 'batch', got {self.engine!r}")
        if self.max_frames is not None and self.max_frames < 1:
            raise _spec_error(f"max_frames must be >= 1, got {self.max_frames!r}")
        if not 0 <= self.seed < 2**63:
            raise _spec_error(f"seed must be an integer in [0, 2**63), got {self.seed!r}")
        ls = self.lambda_safe
        if isinstance(ls, str):
            if ls != LAMBDA_SAFE_AUTO:
                raise _spec_error(
                    f"lambda_safe must be a number or {LAMBDA_SAFE_AUTO!r} (derived from the "
                    f"run's constraint and speed bounds), got {ls!r}"
                )
            if self.lambda_safe_source is None:
                object.__setattr__(self, "lambda_safe_source", LAMBDA_SAFE_AUTO_SOURCE)
        elif ls is not None and not math.isfinite(ls):
            raise _spec_error(f"lambda_safe must be finite, got {ls!r}")
        for role in ROLE_FIELDS:
            _role_parts(role, getattr(self, role))
        if self.robots is not None and not isinstance(self.robots, Robots):
            raise _spec_error(f"robots must be a Robots section, got {self.robots!r}")
        self._check_task()

    def _check_task(self) -> None:
        """``start_m`` as a pair of floats, ``goals_m`` as a tuple of pairs (metres)."""
        if self.start_m is not None:
            xy = _real_list(self.start_m)
            if xy is None or len(xy) != 2:
                raise _spec_error(
                    f"start_m must be two finite numbers [x, y] (m), got {self.start_m!r}"
                )
            object.__setattr__(self, "start_m", tuple(xy))
        if self.goals_m is not None:
            flat = _real_list(self.goals_m)
            items: list[list[float] | None] | None = [flat] if flat is not None else None
            if items is None and not isinstance(self.goals_m, (str, bytes, dict)):
                try:
                    items = [_real_list(g) for g in self.goals_m]
                except TypeError:
                    items = None
            if not items or any(g is None or len(g) != 2 for g in items):
                raise _spec_error(
                    "goals_m must be [x, y] or a list of [x, y] finite numbers (m), got "
                    f"{self.goals_m!r}"
                )
            object.__setattr__(self, "goals_m", tuple(tuple(g) for g in items if g is not None))

    def on_scene(self, scene: Any) -> Any:
        """``scene`` with this run's task (``start_m``, ``goals_m``) in place of its own; the
        scene itself when neither is given.

        Parameters
        ----------
        scene : Scene
            The scene the run is on.
        """
        if self.start_m is None and self.goals_m is None:
            return scene
        import numpy as np

        changes: dict[str, Any] = {}
        if self.start_m is not None:
            changes["start"] = np.array(self.start_m, dtype=float)
        if self.goals_m is not None:
            changes["goals"] = np.array(self.goals_m, dtype=float).reshape(-1, 2)
        return scene.replace(meta={**scene.meta, "task": "run specification"}, **changes)

    def _fallback_one_way(self) -> None:
        """The fallback is a role (``fallback=``): a ``fallback`` among the parameters or
        the safety filter's parameters (the ways of 0.2) moves there, with a
        :class:`DeprecationWarning`; two different fallbacks are an error."""
        filter_name, filter_params = _role_parts("safety_filter", self.safety_filter)
        given = {
            where: value
            for where, value in (
                ("params", self.params.get("fallback")),
                ("safety_filter parameters", filter_params.get("fallback")),
            )
            if value is not None
        }
        if not given:
            return
        import warnings

        names = {repr(v) for v in given.values()}
        if self.fallback is not None:
            names.add(repr(self.fallback))
        if len(names) > 1:
            raise _spec_error(
                f"the fallback is given twice with different values ({', '.join(sorted(names))});"
                " give it once, as the run's fallback"
            )
        warnings.warn(
            f"the fallback given in the {' and the '.join(given)} is the run's fallback role "
            "since 0.3: give fallback=NAME (on the command line --fallback NAME; the other "
            "ways are removed in 0.4, not before 2027-06-30)",
            ConformalControlDeprecationWarning,
            stacklevel=4,
        )
        object.__setattr__(self, "fallback", next(iter(given.values())))
        object.__setattr__(
            self, "params", {k: v for k, v in self.params.items() if k != "fallback"}
        )
        if "fallback" in filter_params:
            rest = {k: v for k, v in filter_params.items() if k != "fallback"}
            object.__setattr__(self, "safety_filter", (filter_name, rest) if rest else filter_name)

    # ------------------------------------------------------------------ roles
    def role(self, name: str) -> tuple[Any, dict[str, Any]]:
        """Role ``name`` as ``(registered name, instance or None; its params)``."""
        if name not in ROLE_FIELDS:
            raise KeyError(name)
        return _role_parts(name, getattr(self, name))

    def roles(self) -> dict[str, tuple[Any, dict[str, Any]]]:
        """Every role as :meth:`role` gives it: role -> (name or instance or None, its
        params)."""
        return {name: _role_parts(name, getattr(self, name)) for name in ROLE_FIELDS}

    def role_name(self, name: str) -> str | None:
        """The registered name of a role (an instance: its class name; None: default)."""
        spec, _ = self.role(name)
        if spec is None or isinstance(spec, str):
            return spec
        return type(spec).__name__

    # ------------------------------------------------------------------ deep parameters
    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """Every field; with ``deep``, also ``<role>__<param>`` for each role's
        parameters and one key per controller parameter."""
        out: dict[str, Any] = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        if deep:
            for role in ROLE_FIELDS:
                spec, params = self.role(role)
                out[role] = spec
                if spec is not None and not isinstance(spec, str):
                    get = getattr(spec, "get_params", None)
                    params = dict(get()) if get is not None else {}
                out.update({f"{role}__{k}": v for k, v in params.items()})
            out.update(self.params)
        return out

    def set_params(self, **changes: Any) -> RunSpec:
        """A copy with ``changes`` applied: fields by name, ``<role>__<param>`` for a
        role's parameter (the role must be given by name), controller parameters by
        name."""
        fields = {f.name for f in dataclasses.fields(self)}
        new: dict[str, Any] = {}
        params = dict(self.params)
        roles: dict[str, tuple[Any, dict[str, Any]]] = {}
        for key, value in changes.items():
            role, sep, sub = key.partition("__")
            if sep:
                if role not in ROLE_FIELDS:
                    raise _spec_error(f"{key}: {role!r} is not a role of a run")
                spec, rp = roles.get(role) or self.role(role)
                if spec is not None and not isinstance(spec, str):
                    raise _spec_error(f"{key}: the {role} is an instance; set its parameter on it")
                if spec is None:
                    raise _spec_error(f"{key}: give the {role} by name first")
                roles[role] = (spec, {**rp, sub: value})
            elif key in fields and key != "params":
                new[key] = value
            elif key in PARAMETERS:
                params[key] = value
            else:
                raise _spec_error(f"unknown run setting {key!r}")
        for role, (spec, rp) in roles.items():
            new[role] = (spec, rp) if rp else spec
        return dataclasses.replace(self, params=params, **new)

    # ------------------------------------------------------------------ keyword settings
    @classmethod
    def from_settings(
        cls, params: dict[str, Any] | None = None, base: RunSpec | None = None, **settings: Any
    ) -> RunSpec:
        """A :class:`RunSpec` from keyword settings, as the functions that run episodes
        take them: fields by name (``predictor=``, ``learn=``, ...), ``params``, and a
        role's parameters as ``<role>_params`` (``predictor_params={"window": 3}``, the
        role given by name); applied on ``base`` (default: the default specification).

        Raises
        ------
        TypeError
            For a keyword that is no setting of a run (with a did-you-mean).
        ValueError
            For ``<role>_params`` without a role given by name.
        """
        spec = cls() if base is None else base
        fields = set(ROLE_FIELDS) | set(OPTION_FIELDS)
        kw: dict[str, Any] = {}
        role_params: dict[str, Any] = {}
        robots: dict[str, Any] = {}
        for key, value in settings.items():
            if key in ROBOT_FIELDS:
                robots[key] = value
            elif key.endswith("_params") and key[: -len("_params")] in ROLE_FIELDS:
                role_params[key[: -len("_params")]] = value
            elif key in fields:
                kw[key] = value
            else:
                import difflib

                known = sorted(
                    fields | set(ROBOT_FIELDS) | {"params"} | {f"{r}_params" for r in ROLE_FIELDS}
                )
                close = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
                hint = f"; did you mean {close[0]!r}?" if close else ""
                raise TypeError(f"unexpected keyword argument {key!r}{hint}")
        for role, given in role_params.items():
            if not given:
                continue
            name, existing = _role_parts(role, kw.get(role, getattr(spec, role)))
            if name is None:
                raise ValueError(f"{role}_params given without a {role} name")
            if not isinstance(name, str):
                raise ValueError(
                    f"{role}_params apply to a {role} given by name, not to an instance"
                )
            kw[role] = (name, {**existing, **dict(given)})
        if params is not None:
            kw["params"] = dict(params)
        if robots:
            kw["robots"] = dataclasses.replace(spec.robots or Robots(), **robots)
        return dataclasses.replace(spec, **kw)

    # ------------------------------------------------------------------ serialisation
    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (``config.json``'s ``spec``); :meth:`from_dict` inverts it.

        Roles given as instances are written as their class name and ``get_params()``
        (they cannot be rebuilt from JSON; :meth:`from_dict` rejects them).
        """
        out: dict[str, Any] = {"params": dict(self.params)}
        for role in ROLE_FIELDS:
            spec, params = self.role(role)
            if spec is None or isinstance(spec, str):
                params = expand_settings(params)  # a settings group as its fields
                out[role] = spec if not params else {"name": spec, "params": params}
            else:
                get = getattr(spec, "get_params", None)
                out[role] = {
                    "instance": type(spec).__name__,
                    "params": {k: repr(v) for k, v in (get() if get else {}).items()},
                }
        for name in OPTION_FIELDS:
            out[name] = getattr(self, name)
        if self.robots is not None:
            out["robots"] = self.robots.as_dict()
        return out

    @classmethod
    def from_dict(cls, data: Any, where: str = "run specification") -> RunSpec:
        """The :class:`RunSpec` of :meth:`as_dict`'s output, every value type-checked.

        Raises
        ------
        InputError
            For an unknown key, a value of the wrong type or a role written from an
            instance (one line naming ``where`` and the key).
        """
        if not isinstance(data, dict):
            raise _spec_error(f"{where} must be a mapping, got {type(data).__name__}")
        known = {"params", "robots", *ROLE_FIELDS, *OPTION_FIELDS}
        unknown = sorted(set(data) - known)
        if unknown:
            raise _spec_error(f"{where}: unknown key {unknown[0]!r}")
        kw: dict[str, Any] = {}
        for key, value in data.items():
            if key == "params" and isinstance(value, dict):
                # JSON has no infinity: config.json writes it as text
                value = {
                    k: float(v) if isinstance(v, str) and v in _INFINITE_TEXT else v
                    for k, v in value.items()
                }
                for k, v in value.items():
                    _check_stored_param(where, str(k), v)
            if key in ROLE_FIELDS and not (value is None or isinstance(value, (str, dict, list))):
                raise _spec_error(
                    f"{where}: {key} must be a registered name or {{'name': ..., 'params': "
                    f"{{...}}}}, got {_short(value)}"
                )
            if key == "robots" and value is not None:
                if not isinstance(value, dict) or set(value) - set(ROBOT_FIELDS):
                    raise _spec_error(
                        f"{where}: robots must be a mapping of {', '.join(ROBOT_FIELDS)}"
                    )
                kw[key] = Robots(**value)
                continue
            if key in ROLE_FIELDS and isinstance(value, dict) and "instance" in value:
                raise _spec_error(
                    f"{where}: the {key} was an instance of {value['instance']}, which a "
                    "file cannot rebuild; give it by registered name"
                )
            if key in ROLE_FIELDS and isinstance(value, dict):
                name, params = _role_parts(key, value)
                kw[key] = (name, params) if params else name
            else:
                kw[key] = value
        try:
            return cls(**kw)
        except TypeError as exc:  # pragma: no cover - the keys were checked above
            raise _spec_error(f"{where}: {exc}") from None
        except InputError as exc:
            message = str(exc)
            if message.startswith(where):
                raise
            raise _spec_error(f"{where}: {message}") from None


# ---------------------------------------------------------------------- the run context
def _doc(text: str) -> dict[str, str]:
    return {"doc": text}


@dataclass(frozen=True)
class RunContext:
    """The values a run hands the plugins it builds, each only to a plugin that asks for it.

    A plugin class declares the run values it takes in its capabilities
    (:attr:`Capabilities.run_values <conformal_control.core.capabilities.Capabilities.run_values>`:
    constructor argument -> one of these field names, e.g. ``{"d_c":
    "barrier_distance"}``); :meth:`arguments` passes exactly those the caller did not give.
    Nothing is passed because an argument happens to share a name with a run value: a
    predictor whose own ``v_max`` is the pedestrians' speed cap keeps it. A field left at
    None is a value this run does not fix (the plugin's own default then applies). Lengths
    and times are SI.
    """

    collision_distance: float | None = field(
        default=None, metadata=_doc("robot radius + agent radius (m)")
    )
    barrier_distance: float | None = field(
        default=None, metadata=_doc("collision_distance + barrier_margin (m): the barrier's d_c")
    )
    safe_distance: float | None = field(
        default=None, metadata=_doc("collision_distance + 1 m: a safety loss's d_safe")
    )
    barrier_margin: float | None = field(
        default=None, metadata=_doc("margin the barrier adds to the collision distance (m)")
    )
    v_max: float | None = field(default=None, metadata=_doc("the robot's speed limit (m/s)"))
    K_att: float | None = field(
        default=None, metadata=_doc("gain of the attractive-field reference (1/s)")
    )
    K_acc: float | None = field(
        default=None, metadata=_doc("gain of the velocity-tracking plant (1/s)")
    )
    K_rep: float | None = field(default=None, metadata=_doc("gain of the APF barrier's repulsion"))
    rho0: float | None = field(
        default=None, metadata=_doc("influence distance of the APF barrier (m)")
    )
    convention: str | None = field(
        default=None, metadata=_doc("the APF barrier's distance convention")
    )
    delta: float | None = field(
        default=None, metadata=_doc("the APF barrier's smoothing length (m)")
    )
    speed_sides: int | None = field(
        default=None, metadata=_doc("sides of the exact filter's speed polygon (0: a box)")
    )
    substeps: int | None = field(default=None, metadata=_doc("control instants per frame"))
    loss_scale: float | None = field(
        default=None, metadata=_doc("scale c of the gap loss's squashing (m/s)")
    )
    seed: int | None = field(
        default=None, metadata=_doc("the run's seed (a plugin's random_state)")
    )
    fallback: Any = field(
        default=None, metadata=_doc("the run's fallback (a registered name or a Fallback)")
    )
    epsilon: float | None = field(default=None, metadata=_doc("target average loss"))
    eta: float | None = field(default=None, metadata=_doc("learning rate (SI)"))
    lambda_init: float | None = field(default=None, metadata=_doc("initial lambda (SI)"))
    lambda_min: float | None = field(
        default=None, metadata=_doc("lower clipping bound of lambda (SI)")
    )
    lambda_max: float | None = field(
        default=None, metadata=_doc("upper clipping bound of lambda (SI)")
    )
    constraint: Any = field(
        default=None, metadata=_doc("the run's ConformalConstraint (barrier and class-K gain)")
    )
    predictor: Any = field(default=None, metadata=_doc("the run's predictor (an instance)"))
    safety_filter: Any = field(default=None, metadata=_doc("the run's safety filter (an instance)"))
    reference: Any = field(
        default=None, metadata=_doc("the run's reference controller (an instance)")
    )
    dynamics: Any = field(default=None, metadata=_doc("the run's plant (an instance)"))

    def replace(self, **changes: Any) -> RunContext:
        """A copy with ``changes`` (run value name -> value) applied."""
        return dataclasses.replace(self, **changes)

    def arguments(self, cls: type, given: dict[str, Any] | None = None) -> dict[str, Any]:
        """The keyword arguments to build ``cls`` with: the run values its capabilities
        declare (``run_values``) that this run fixes and ``given`` does not set, then
        ``given`` unchanged (a caller's value always wins; a settings group given whole,
        ``limits=Limits(...)``, also wins over a run value for one of its fields,
        ``limits__v_max``).

        Parameters
        ----------
        cls : type
            The plugin class (its ``capabilities.run_values`` are read).
        given : dict, optional
            The caller's arguments.
        """
        given = dict(given or {})
        caps = getattr(cls, "capabilities", None)
        declared: dict[str, str] = dict(getattr(caps, "run_values", {}))
        renamed: dict[str, str] = getattr(cls, "renamed_params", {})
        keys = {renamed.get(k, k) for k in given}
        whole = {k for k in keys if "__" not in k}  # a group given as one object
        out: dict[str, Any] = {}
        for argument, name in declared.items():
            value = getattr(self, name)
            if value is None or argument in keys or argument.partition("__")[0] in whole:
                continue
            out[argument] = value
        out.update(given)
        return out


#: The documented run values (name -> what it is), the fields of :class:`RunContext`: the
#: names a plugin may declare in its ``run_values``.
RUN_VALUES: dict[str, str] = {f.name: f.metadata["doc"] for f in dataclasses.fields(RunContext)}
