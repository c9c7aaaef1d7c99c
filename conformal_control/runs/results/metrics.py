"""Episode metrics: one dataclass, every metric with its unit and meaning.

:class:`EpisodeMetrics` is the single list of what an episode reports: the CLI prints
:attr:`EpisodeMetrics.SUMMARY`, sweeps and the benchmark store :meth:`EpisodeMetrics.columns`,
``metrics.json`` is :meth:`EpisodeMetrics.as_dict`. It reads like a dict (``m["t_goal"]``)
so reports can treat stored rows and live results alike.

Counting conventions (all "until the goal is reached or the episode ends"): a *collision
frame* is a video frame whose smallest centre distance robot-pedestrian is below
d_c = robot radius + pedestrian radius; *personal space* is a surface gap
(centre distance - d_c) below 0.5 m.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

__all__ = [
    "PERSONAL_SPACE",
    "EpisodeMetrics",
    "MetricsTable",
    "episode_metrics",
    "format_value",
    "metric",
    "metric_fields",
    "plain",
]

#: Surface gap (m) under which the robot is inside a pedestrian's personal space.
PERSONAL_SPACE = 0.5


def metric(unit: str, doc: str, default: Any = None) -> Any:
    """A metric field: ``unit`` is "-" (count/flag/dimensionless), an SI unit, or
    ``"lambda"`` (the scene's unit of lambda, e.g. 1/frame for SDD scenes)."""
    return field(default=default, metadata={"unit": unit, "doc": doc})


_m = metric  # a short name for the table below


class MetricsTable(Mapping[str, Any]):
    """What a run measured: a dataclass of metrics, each field with its unit and meaning
    (``metadata``), read like a dict, written as JSON, printed as aligned lines.

    One table type for one robot (:class:`EpisodeMetrics`) and a fleet
    (:class:`~conformal_control.runs.results.multi_metrics.FleetMetrics`).
    """

    #: What ``format()`` prints by default.
    SUMMARY: ClassVar[tuple[str, ...]] = ()
    #: Fields that are not one table column each (dicts, lists).
    NON_SCALAR: ClassVar[frozenset[str]] = frozenset({"units"})
    units: dict[str, str] | None

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """Every metric, in the table's order."""
        cached: tuple[str, ...] | None = cls.__dict__.get("_names")
        if cached is None:
            cached = tuple(f.name for f in dataclasses.fields(cls))  # type: ignore[arg-type]
            cls._names = cached  # type: ignore[attr-defined]  # per class, set once
        return cached

    def __getitem__(self, key: str) -> Any:
        if key not in self.names():
            raise KeyError(key)
        return getattr(self, key)

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self.names())

    @classmethod
    def columns(cls) -> tuple[str, ...]:
        """The scalar metrics (one table column each)."""
        return tuple(n for n in cls.names() if n not in cls.NON_SCALAR)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dict: non-finite floats become None, numpy scalars Python ones."""
        return {name: plain(getattr(self, name)) for name in self.names()}

    def unit(self, name: str) -> str:
        """The unit of metric ``name`` ("-" when it has none)."""
        return (self.units or {}).get(name, "-")

    def format(self, keys: tuple[str, ...] | None = None) -> str:
        """Metrics as aligned ``name  value unit`` lines with sensible precision."""
        keys = keys or self.SUMMARY
        width = max(len(k) for k in keys)
        lines = []
        for k in keys:
            unit = self.unit(k)
            text = format_value(getattr(self, k))
            suffix = f" {unit}" if unit != "-" and text not in ("-", "none") else ""
            lines.append(f"{k:<{width}}  {text}{suffix}")
        return "\n".join(lines)


@dataclass
class EpisodeMetrics(MetricsTable):
    """What one episode of the flagship measured (see each field's ``metadata``)."""

    # -- task -------------------------------------------------------------------------
    success: bool = _m("-", "goal reached within the time limit and no collision frame", False)
    goal_reached: bool = _m("-", "the last goal was reached before the data or time ran out", False)
    t_goal: float | None = _m("s", "time to reach the last goal (None if not reached)")
    path_length: float | None = _m("m", "length of the robot's path")
    mean_speed: float | None = _m("m/s", "path length / elapsed time")
    # -- safety -----------------------------------------------------------------------
    n_collide: int = _m("-", "collision frames (centre distance < d_c)", 0)
    any_collision: bool = _m("-", "at least one collision frame", False)
    d_min: float | None = _m("m", "smallest centre distance to a pedestrian")
    time_in_personal_space: float = _m("s", "time with a surface gap < 0.5 m", 0.0)
    # -- collision accounting (conformal_control.runs.results.collisions) -----------------------
    n_collision_events: int = _m("-", "runs of frames with one pedestrian closer than d_c", 0)
    n_collide_avoidable: int = _m(
        "-", "collision frames a point robot could have avoided from first sensing (no pop-in)", 0
    )
    n_collide_unavoidable: int = _m("-", "collision frames proven unavoidable (no pop-in)", 0)
    n_collide_undecided: int = _m("-", "collision frames neither proven (no pop-in)", 0)
    n_collide_at_fault: int = _m(
        "-", "collision frames with the robot moving toward its nearest pedestrian", 0
    )
    n_collide_popin: int = _m("-", "collision frames of pedestrians that popped in nearby", 0)
    penetration_max: float | None = _m("m", "deepest intrusion, d_c - distance")
    collision_events: list[dict[str, Any]] | None = _m("-", "every collision event, classified")  # noqa: RUF009
    # -- conformal variable and loss --------------------------------------------------
    l_avg: float | None = _m("-", "average loss over the lambda updates (learning runs)")
    l_avg_applied: float | None = _m("-", "average loss with the lambda actually applied")
    l_mean: float | None = _m("-", "average loss over scored intervals (also without learning)")
    epsilon: float | None = _m("-", "target average loss")
    eta: float | None = _m("lambda", "learning rate (0 without learning)")
    lambda_final: float | None = _m("lambda", "lambda after the last update")
    lambda_mean: float | None = _m("lambda", "mean of lambda_k over the scored intervals")
    lambda_min: float | None = _m("lambda", "smallest lambda_k over the scored intervals")
    lambda_max: float | None = _m("lambda", "largest lambda_k over the scored intervals")
    n_updates: int = _m("-", "lambda updates", 0)
    n_scored: int = _m("-", "intervals with a loss", 0)
    n_intervals: int = _m("-", "intervals", 0)
    n_unscored: int = _m("-", "intervals without a loss (nothing sensed)", 0)
    # -- safety filter ----------------------------------------------------------------
    n_steps: int = _m("-", "control instants", 0)
    n_infeasible: int = _m("-", "control instants whose rows were infeasible at lambda_k", 0)
    n_fallback: int = _m("-", "control instants decided by the fallback", 0)
    fallback_share: float = _m("-", "n_fallback / n_steps", 0.0)
    n_qp_solves: int = _m("-", "solver calls (QPs and LPs)", 0)
    n_lambda_clipped: int = _m("-", "updates whose lambda was clipped", 0)
    # -- guarantee --------------------------------------------------------------------
    identity_residual: float | None = _m("-", "|mean loss - identity| (fixed-step rules)")
    rule: str | None = _m("-", "update rule")
    guarantee: str | None = _m("-", "guarantee kind of the rule")
    lambda_safe: float | None = _m("lambda", "lambda_safe given for Theorem 2")
    lambda_safe_source: str | None = _m("-", "where lambda_safe came from")
    theorem2_bound: float | None = _m("-", "Theorem-2 bound on the average loss")
    theorem2_bound_met: bool | None = _m("-", "average loss <= the bound (arithmetic only)")
    theorem2_holds: bool | None = _m("-", "verdict is 'holds' (bound met and premise tested)")
    theorem2_verdict: str | None = _m("-", "holds / violated / premise_fails / ...")
    theorem2_premise_tested: int | None = _m("-", "updates with lambda_k <= lambda_safe")
    theorem2_premise_violations: int | None = _m("-", "of those, updates with loss > epsilon")
    theorem2_assumption: bool | None = _m("-", "lambda_1 >= lambda_safe - eta (and clipping)")
    long_run_bound: float | None = _m("-", "the rule's bound on |mean loss - epsilon|")
    long_run_holds: bool | None = _m("-", "|mean loss - epsilon| <= long_run_bound")
    # -- lambda per agent (lambda_per="agent"; None otherwise) ------------------------
    n_agents: int | None = _m("-", "agents with a loss (lambda per agent)")
    n_agents_checked: int | None = _m(
        "-", "of those, agents with >= 10 losses (checked one by one)"
    )
    n_agents_bound_met: int | None = _m("-", "checked agents whose average meets their bound")
    agent_l_avg_median: float | None = _m(
        "-", "median over the checked agents of their average loss"
    )
    agent_l_avg_max: float | None = _m("-", "largest average loss of a checked agent")
    n_agents_premise_tested: int | None = _m(
        "-", "agents with an update at lambda_j <= lambda_safe (with lambda_safe)"
    )
    n_agents_premise_failed: int | None = _m(
        "-", "of those, agents with a loss > epsilon at lambda_j <= lambda_safe"
    )
    n_premise_checks: int | None = _m(
        "-", "(agent, interval) losses re-evaluated at lambda_safe (with lambda_safe)"
    )
    n_premise_exceeded: int | None = _m("-", "of those, losses above epsilon at lambda_safe")
    n_agents_premise_exceeded: int | None = _m(
        "-", "agents with a loss above epsilon at lambda_safe at some interval"
    )
    agents: dict[str, Any] | None = _m("-", "per checked agent: losses, average loss, bound")  # noqa: RUF009 (a field)
    # -- feasibility floor ------------------------------------------------------------
    lambda_floor: float | None = _m("lambda", "-a h_max: below it a far agent's row fails")
    epsilon_floor: float | None = _m("-", "s(lambda_floor): targets at or below are unattainable")
    epsilon_attainable: bool | None = _m("-", "epsilon > epsilon_floor")
    # -- data and predictor -----------------------------------------------------------
    n_nonfinite_predictions: int = _m("-", "agent-intervals with non-finite predictions", 0)
    n_truth_missing: int = _m("-", "(agent, instant) pairs without truth (left the view)", 0)
    predictor_info: dict[str, Any] | None = _m("-", "the predictor's counters and messages")  # noqa: RUF009 (a field)
    frames: int = _m("-", "video frames simulated", 0)
    wall_s: float = _m("s", "wall time of the control loop", 0.0)
    units: dict[str, str] | None = _m("-", "unit of each metric")  # noqa: RUF009 (a field)

    NON_SCALAR: ClassVar[frozenset[str]] = frozenset(
        {"predictor_info", "units", "collision_events", "agents"}
    )
    #: What ``conformal-control run`` prints.
    SUMMARY: ClassVar[tuple[str, ...]] = (
        "success",
        "t_goal",
        "goal_reached",
        "n_collide",
        "d_min",
        "time_in_personal_space",
        "l_avg",
        "l_avg_applied",
        "lambda_final",
        "n_updates",
        "n_fallback",
        "fallback_share",
        "n_qp_solves",
        "identity_residual",
        "rule",
        "guarantee",
        "theorem2_bound",
        "theorem2_verdict",
        "long_run_bound",
        "long_run_holds",
        "frames",
        "wall_s",
    )


def metric_fields() -> dict[str, tuple[str, str]]:
    """metric -> (unit, meaning), for docs and ``--help``."""
    fields = dataclasses.fields(EpisodeMetrics)
    return {f.name: (f.metadata["unit"], f.metadata["doc"]) for f in fields}


def format_value(v: Any) -> str:
    """A metric value with sensible precision (4 significant digits, no float noise)."""
    if v is None:
        return "none"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        x = float(v)
        if not math.isfinite(x):
            return str(x)
        if x == 0:
            return "0"
        if abs(x) < 1e-3 or abs(x) >= 1e5:
            return f"{x:.3g}"
        return f"{x:.4g}"
    return str(v)


def plain(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [plain(v) for v in x]
    if isinstance(x, (np.floating, float)):
        x = float(x)
        return x if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def episode_metrics(
    *,
    trajectory: dict[str, np.ndarray],
    collision_distance: float,
    fps: float,
    t_goal: float | None,
    lambdas: np.ndarray,
    lam_unit: float,
    lam_unit_name: str,
    **figures: Any,
) -> EpisodeMetrics:
    """Build :class:`EpisodeMetrics` from the frame log and the loop's figures.

    Parameters
    ----------
    trajectory : dict of arrays
        The environment's frame log (``x``, ``y``, ``t``, ``d_min`` per frame, m and s).
    collision_distance : float
        d_c (m) as resolved for the run.
    fps : float
        Frame rate of the log.
    t_goal : float or None
    lambdas : ndarray
        lambda_k (SI) of the scored intervals.
    lam_unit : float
        SI value of one scene unit of lambda (to report lambda in scene units).
    lam_unit_name : str
    **figures
        Every other field of :class:`EpisodeMetrics`, already in its reported unit.
    """
    d = np.asarray(trajectory["d_min"], dtype=float)
    x, y = np.asarray(trajectory["x"]), np.asarray(trajectory["y"])
    t = np.asarray(trajectory["t"], dtype=float)
    steps = np.hypot(np.diff(x), np.diff(y))
    path = float(steps.sum()) if steps.size else 0.0
    elapsed = float(t[-1] - t[0]) if t.size > 1 else 0.0
    with np.errstate(invalid="ignore"):
        n_collide = int(np.sum(d < collision_distance))
        personal = int(np.sum(d - collision_distance < PERSONAL_SPACE))
    lam = np.asarray(lambdas, dtype=float) / lam_unit
    reached = t_goal is not None
    units = {
        f.name: (lam_unit_name if f.metadata["unit"] == "lambda" else f.metadata["unit"])
        for f in dataclasses.fields(EpisodeMetrics)
    }
    units["lambda"] = lam_unit_name  # the unit of lambda itself (plots, animation)
    return EpisodeMetrics(
        success=bool(reached and n_collide == 0),
        goal_reached=reached,
        t_goal=t_goal,
        path_length=path,
        mean_speed=path / elapsed if elapsed > 0 else None,
        n_collide=n_collide,
        any_collision=n_collide > 0,
        d_min=float(np.nanmin(d)) if np.isfinite(d).any() else None,
        time_in_personal_space=personal / fps,
        lambda_mean=float(lam.mean()) if lam.size else None,
        lambda_min=float(lam.min()) if lam.size else None,
        lambda_max=float(lam.max()) if lam.size else None,
        frames=int(t.size),
        units=units,
        **figures,
    )
