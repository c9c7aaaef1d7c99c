"""The ETH/UCY planar protocol of the conformal sampling-MPC papers (suite ``fcp-planar``).

ACP-MPC (Dixit et al. 2023), CC-MPC (the conformal controller of Lekeufack et al. 2024),
ECP-MPC (Shin et al. 2025) and FCP-MPC (2026) were compared under one closed-loop protocol
on five ETH/UCY test recordings, with a published table (CORE-SNU/FCP-MPC,
``planar/runner_2d.py``, ``planar/sims/sim_*.py`` and ``planar/make_table_2d.py``, MIT
licence). This module states that protocol as those files apply it, runs our decision
families through it, and holds the published table beside our rows. Facts and figures are
carried over; none of that code is used.

**Tasks** (:data:`TASKS`): per dataset, the recording, the start time steps (13 scenarios in
all), the offset mapping a time step to the recording's frame (``frame = 10 * timestep +
frame_offset``), the step limit, the robot's initial pose (x, y, heading) and its goal.

**Robot**: a unicycle of radius 0.4 m, ``-0.8 <= v <= 0.8`` m/s, ``|omega| <= 0.7`` rad/s,
moved by forward Euler over steps of 0.4 s. Pedestrians have radius ``1/sqrt(2)`` m; a
collision is a centre distance below 1.107 m.

**Time.** The scenario walks the recording's time steps from its start. A time step counts
as a *step* only when at least one pedestrian has a history there (is present at that
sample and at the previous one): the published runs iterate over the keys of their
prediction files, which are exactly those time steps (checked here on eth, hotel and zara1:
identical), so time steps without such a pedestrian pass with the robot frozen and the
step counter unchanged. The pedestrians of a step are those with a history.

**Warm-up.** For the first 15 steps the robot stands still (no decision; the families
still receive the observations, so a conformal method may calibrate) and nothing is
recorded; the counter keeps running, so steps to goal include them.

**Recorded steps.** From step 15 on, before the controller decides: the goal is reached
when the robot is within 0.6 m of it (the scenario ends there: from then on nothing is
recorded); otherwise the step is recorded, a collision if a pedestrian is closer than
1.107 m, infeasible if the controller then reports no feasible control. The scenario ends
after ``max_steps`` steps (or when the recording ends, which the published scenarios
never reach).

**Metrics** (:data:`METRICS`), per scenario, then averaged over a dataset's scenarios:
collision rate (collision steps / recorded steps), infeasible rate (infeasible steps /
recorded steps), steps to goal (the step count at which the goal was reached; a scenario
that did not reach it counts as ``max_steps``, and the dataset's figure reads "timeout"
when the average is within 0.5 of ``max_steps``, i.e. when no scenario reached it, as the
published table's code does), controller time per step (ms, mean over the decided steps).
A scenario with no recorded step is left out (the published code drops such scenarios).

**eth's time base.** The published protocol uses ``biwi_eth.txt`` as it is, whose 0.4 s
steps play the original recording about 1.67 times too fast (pedestrians at 2.45 m/s
median); this protocol follows it for the comparison.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Generator, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, cast

import numpy as np

from ...predictors.base import Forecast, PredictionQuery, Predictor

__all__ = [
    "GOAL_TOLERANCE_M",
    "METRICS",
    "PED_RADIUS_M",
    "PLANAR_METHODS",
    "PUBLISHED",
    "ROBOT",
    "STEP_S",
    "TASKS",
    "WARM_UP_STEPS",
    "PlanarMethod",
    "PlanarRecording",
    "PlanarTask",
    "ScenarioResult",
    "dataset_metrics",
    "planar_table",
    "reusable_rows",
    "run_planar",
    "run_scenario",
    "run_scenarios",
    "scenario_metrics",
]

SUITE = "fcp-planar"
STEP_S = 0.4
FRAMES_PER_STEP = 10
WARM_UP_STEPS = 15
GOAL_TOLERANCE_M = 0.6
PED_RADIUS_M = math.sqrt(0.5)  # 1/sqrt(2) m
#: The robot: a unicycle (limits in m/s and rad/s, radius in m).
ROBOT: dict[str, Any] = {
    "model": "unicycle",
    "radius_m": 0.4,
    "v_min_mps": -0.8,
    "v_max_mps": 0.8,
    "omega_min_radps": -0.7,
    "omega_max_radps": 0.7,
}
COLLISION_M = ROBOT["radius_m"] + PED_RADIUS_M
#: Length of a history handed to the predictors (samples, the current one included).
HISTORY_SAMPLES = 8


PI = math.pi


@dataclass(frozen=True)
class PlanarTask:
    """One dataset of the protocol.

    Attributes
    ----------
    dataset : str
        ``eth``, ``hotel``, ``univ``, ``zara1`` or ``zara2``.
    recording : str
        The ETH/UCY recording (``biwi_eth``, ...).
    start_timesteps : tuple of int
        One scenario per start time step.
    frame_offset : int
        ``frame = 10 * timestep + frame_offset``.
    max_steps : int
    init_pose : (x, y, heading)
        m, m, rad.
    goal : (x, y)
        m.
    part : (int, int) or None
        The time steps (first, last) of the recording's part the scenarios are drawn from
        (``fcp-planar-dense``'s dev or test part), None: the whole recording. An
        offline-calibrated ``fcp_mpc`` calibrates once for the part (:func:`scenario_envelope`).
    """

    dataset: str
    recording: str
    start_timesteps: tuple[int, ...]
    frame_offset: int
    max_steps: int
    init_pose: tuple[float, float, float]
    goal: tuple[float, float]
    part: tuple[int, int] | None = None


#: The protocol's tasks, as published. univ: the published repository names the dataset
#: univ without saying which file; ``students001`` (the one whose Trajectron++ predictions
#: the published runs used is not available) is the assumption here.
TASKS: dict[str, PlanarTask] = {
    t.dataset: t
    for t in (
        PlanarTask("eth", "biwi_eth", (732, 339, 653), 780, 100, (5.0, 1.0, PI / 2), (3.0, 10.0)),
        PlanarTask(
            "hotel", "biwi_hotel", (1001, 1245, 1582), 0, 100, (-1.5, 0.0, -PI / 2), (2.0, -6.0)
        ),
        PlanarTask("univ", "students001", (100,), 0, 300, (3.5, 2.0, PI / 4), (11.5, 8.5)),
        PlanarTask("zara1", "crowds_zara01", (100, 200, 300), 0, 100, (12.0, 5.0, PI), (3.0, 6.0)),
        PlanarTask(
            "zara2", "crowds_zara02", (100, 200, 300), 10, 100, (1.0, 6.0, 0.0), (14.0, 5.0)
        ),
    )
}

#: Metric definitions (what every figure of the table means).
METRICS: dict[str, str] = {
    "collision_rate": "collision steps / recorded steps (after warm-up, until the goal or the "
    "step limit), averaged over a dataset's scenarios",
    "infeasible_rate": "steps at which the controller reported no feasible control / recorded "
    "steps, averaged over a dataset's scenarios",
    "steps_to_goal": "step count (warm-up included) at which the goal was reached, a scenario "
    "that did not reach it counting as max_steps, averaged; 'timeout' when the average is "
    "within 0.5 of max_steps",
    "ctrl_time_ms": "controller wall time per decided step (ms), without the predictor's own "
    "time, mean per scenario, averaged",
}

#: The published table (collision rate, infeasible rate, steps to goal, ms per step);
#: ``None`` where the method has no hard constraint (no infeasibility).
PUBLISHED: dict[str, dict[str, tuple[float, float | None, float | str, float]]] = {
    "eth": {
        "ACP-MPC": (0.079, 0.284, 79.0, 0.94),
        "CC-MPC": (0.036, None, 96.7, 1.08),
        "ECP-MPC": (0.047, 0.239, "timeout", 39.60),
        "FCP-MPC (hard)": (0.069, 0.589, 83.7, 0.89),
        "FCP-MPC (soft)": (0.175, None, 41.0, 1.75),
    },
    "hotel": {
        "ACP-MPC": (0.041, 0.428, 80.3, 1.23),
        "CC-MPC": (0.049, None, 99.3, 1.48),
        "ECP-MPC": (0.020, 0.213, 85.7, 50.16),
        "FCP-MPC (hard)": (0.080, 0.143, 46.3, 1.60),
        "FCP-MPC (soft)": (0.045, None, 35.7, 1.97),
    },
    "univ": {
        "ACP-MPC": (0.000, 0.660, "timeout", 4.70),
        "CC-MPC": (0.053, None, "timeout", 5.78),
        "ECP-MPC": (0.081, 0.365, "timeout", 74.16),
        "FCP-MPC (hard)": (0.333, 0.550, "timeout", 2.58),
        "FCP-MPC (soft)": (0.333, None, 96.0, 6.56),
    },
    "zara1": {
        "ACP-MPC": (0.188, 0.573, "timeout", 0.88),
        "CC-MPC": (0.041, None, 90.0, 1.07),
        "ECP-MPC": (0.094, 0.161, 82.0, 53.90),
        "FCP-MPC (hard)": (0.204, 0.341, 81.0, 1.00),
        "FCP-MPC (soft)": (0.191, None, 38.0, 1.75),
    },
    "zara2": {
        "ACP-MPC": (0.262, 0.628, 94.0, 1.09),
        "CC-MPC": (0.056, None, "timeout", 1.25),
        "ECP-MPC": (0.176, 0.318, "timeout", 57.26),
        "FCP-MPC (hard)": (0.203, 0.347, 84.0, 1.20),
        "FCP-MPC (soft)": (0.189, None, 65.0, 2.05),
    },
}


# ------------------------------------------------------------------------------ recording
class PlanarRecording:
    """An ETH/UCY recording indexed by sample (``frame / 10``), for the protocol.

    Parameters
    ----------
    path : path
        The recording's file (``frame ped_id x y``, metres, a row every 10 frames).
    """

    def __init__(self, path: str | Path) -> None:
        from ...data.ethucy import read_ethucy

        tracks = read_ethucy(path)
        step = float(tracks.meta.get("frame_step", FRAMES_PER_STEP))
        if step != FRAMES_PER_STEP:
            raise ValueError(
                f"{path}: samples every {step:g} frames; the planar protocol needs a row "
                f"every {FRAMES_PER_STEP} frames"
            )
        self.path = str(path)
        lo, hi = tracks.frame_range()
        self.first, self.last = lo, hi
        ids, pos = tracks.dense(lo, hi)
        self.ids = ids.astype(np.int64)
        self.positions = pos  # (samples, M, 2), NaN where absent

    def sample(self, timestep: int, frame_offset: int) -> int:
        """Index into :attr:`positions` of a protocol time step."""
        return int(timestep) + frame_offset // FRAMES_PER_STEP - self.first

    def pedestrians(self, i: int) -> np.ndarray:
        """Columns of the pedestrians with a history at sample ``i`` (present at ``i`` and
        ``i - 1``)."""
        if i < 1 or i >= self.positions.shape[0]:
            return np.zeros(0, dtype=np.int64)
        now = np.isfinite(self.positions[i, :, 0])
        before = np.isfinite(self.positions[i - 1, :, 0])
        return np.flatnonzero(now & before)

    def history(self, i: int, cols: np.ndarray, length: int = HISTORY_SAMPLES) -> np.ndarray:
        """Positions of ``cols`` at samples ``i - length + 1 .. i``, shape (N, length, 2)."""
        out = np.full((cols.size, length, 2), np.nan)
        lo = i - length + 1
        a = max(lo, 0)
        out[:, a - lo :] = self.positions[a : i + 1, cols].transpose(1, 0, 2)
        return out

    def at(self, i: int, cols: np.ndarray) -> np.ndarray:
        """Positions of ``cols`` at sample ``i`` (NaN where absent or beyond the data)."""
        if 0 <= i < self.positions.shape[0]:
            out: np.ndarray = self.positions[i, cols]
            return out
        return np.full((cols.size, 2), np.nan)


@lru_cache(maxsize=8)
def _recording(path: str) -> PlanarRecording:
    return PlanarRecording(path)


def recording(task: PlanarTask, data_root: str | Path | None = None) -> PlanarRecording:
    """The task's recording (read once per process)."""
    from ...data.ethucy import ethucy_recording

    return _recording(str(ethucy_recording(task.recording, data_root)))


# ------------------------------------------------------------------------------ methods
#: How a method's row is defined: by the published code ("published", the row's name
#: follows the published method) or by us ("ours").
DEFINITIONS = ("published", "ours")
#: How ``fcp_mpc`` is calibrated on the protocol
#: (:mod:`~conformal_control.experiments.bench.planar_fcp`):
#: every time step of the recording (the published runs'), or every time step outside the
#: scenario's window (ours: the test window is not calibrated on; in the dense suite, the
#: other part of the recording).
CALIBRATIONS = ("recording", "held_out")


@dataclass(frozen=True)
class PlanarMethod:
    """One of our methods on the protocol: a decision family with its loss and rule.

    Attributes
    ----------
    name : str
    family : {"cbf", "mpc", "acp_mpc", "ecp_mpc", "fcp_mpc", "soft_mpc"}
    description : str
    learn : bool
    family_params : mapping
        Overrides of the family's parameters (SI).
    loss, rule : str
        Registered names.
    loss_params, rule_params : mapping
    definition : {"published", "ours"}
        Whether the row follows a published method's definition (then ``published`` names
        the published table's row) or is ours.
    published : str or None
        The published row a ``published`` definition reproduces.
    predictor : str or None
        A predictor replacing the run's (``oracle``: the recording's true future).
    calibration : {"recording", "held_out"} or None
        How an ``fcp_mpc`` method's envelopes are calibrated (None: online, from the
        episode's own past).
    """

    name: str
    family: str
    description: str
    learn: bool = True
    family_params: Mapping[str, Any] = field(default_factory=dict)
    loss: str = "cbf_gap"
    loss_params: Mapping[str, Any] = field(default_factory=dict)
    rule: str = "fixed_eta"
    rule_params: Mapping[str, Any] = field(default_factory=dict)
    definition: str = "ours"
    published: str | None = None
    predictor: str | None = None
    calibration: str | None = None

    def __post_init__(self) -> None:
        if self.definition not in DEFINITIONS:
            raise ValueError(f"definition must be one of {DEFINITIONS}, got {self.definition!r}")
        if self.calibration is not None and self.calibration not in CALIBRATIONS:
            raise ValueError(
                f"calibration must be one of {CALIBRATIONS} or None, got {self.calibration!r}"
            )

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        return {k: dict(v) if isinstance(v, Mapping) else v for k, v in d.items()}


#: The CBF's parameters on the protocol: the built-in SI scene's defaults (a, K_rep, rho0,
#: K_att, eta, epsilon, loss scale), not tuned on the protocol.
CBF_PARAMS: dict[str, float] = {
    "a": 2.0,
    "K_rep": 0.5,
    "rho0": 5.0,
    "K_att": 1.0,
    "lookahead": 0.2,
}
#: The MPC's search: the published runs' budget (1,200 sampled sequences, 12 steps of
#: 0.4 s, commands held for 2 steps). With no safe sample our MPCs take the plan that
#: intrudes least (``least_violation``) and check the safe distance over whole plan steps;
#: the rows of a published definition stand still (``brake``, the published runs' velocity
#: 0) and check step ends only (:data:`PUBLISHED_SEARCH`).
MPC_PARAMS: dict[str, Any] = {
    "sampling__n_samples": 1200,
    "sampling__horizon": 12,
    "sampling__dt_plan": STEP_S,
    "sampling__hold": 2,
    "fallback": "least_violation",
}
#: What a published definition changes in :data:`MPC_PARAMS`.
PUBLISHED_SEARCH: dict[str, Any] = {"fallback": "brake", "continuous": False}
_SHORTFALL = {"d_safe": 2.0, "d_c": COLLISION_M}
_CC_RULE = {"epsilon": 0.1, "eta": 0.5, "lambda_min": -2.0, "lambda_max": COLLISION_M}
#: FCP-MPC's published adaptation (``CPOnlineAdapter``): target 0.1, step 0.05, the radii's
#: multiplier in [0.2, 5] (lambda = 1 - multiplier), starting at 1.
_FCP_RULE = {"epsilon": 0.1, "eta": 0.05, "lambda_init": 0.0, "lambda_min": -4.0, "lambda_max": 0.8}

PLANAR_METHODS: dict[str, PlanarMethod] = {
    m.name: m
    for m in (
        PlanarMethod("cbf_nolearn", "cbf", "conformal CBF family, lambda = 0, no learning", False),
        PlanarMethod(
            "cbf_conformal",
            "cbf",
            "conformal CBF (Algorithm 1): fixed-eta rule on the gap loss, eps = -0.1",
            rule_params={"epsilon": -0.1, "eta": 2.0},
        ),
        PlanarMethod(
            "cbf_oracle",
            "cbf",
            "conformal CBF family planning with the recording's true future, lambda = 0",
            False,
            predictor="oracle",
        ),
        PlanarMethod(
            "mpc",
            "mpc",
            "sampling MPC, safe distance d_c (lambda = 0), no learning",
            False,
            loss="distance_shortfall",
            loss_params=_SHORTFALL,
        ),
        PlanarMethod(
            "oracle_mpc",
            "mpc",
            "sampling MPC planning with the recording's true future, safe distance d_c, no "
            "learning: what perfect prediction gives this planner",
            False,
            loss="distance_shortfall",
            loss_params=_SHORTFALL,
            predictor="oracle",
        ),
        PlanarMethod(
            "blind_mpc",
            "mpc",
            "sampling MPC with safe distance 0: a robot that ignores the pedestrians",
            False,
            family_params={"d_c": 0.0},
            loss="distance_shortfall",
            loss_params=_SHORTFALL,
        ),
        PlanarMethod(
            "mpc_brake",
            "mpc",
            "mpc standing still when no sample is safe (the alternative to least_violation, "
            "compared on the dense suite's dev part)",
            False,
            family_params={"fallback": "brake"},
            loss="distance_shortfall",
            loss_params=_SHORTFALL,
        ),
        PlanarMethod(
            "cc_mpc",
            "mpc",
            "conformal controller (CDT): sampling MPC, safe distance d_c - lambda, "
            "fixed-eta rule on the distance shortfall below 2 m, eps = 0.1",
            loss="distance_shortfall",
            loss_params=_SHORTFALL,
            rule_params=_CC_RULE,
        ),
        PlanarMethod(
            "cc_mpc_brake",
            "mpc",
            "cc_mpc standing still when no sample is safe (the published runs' fallback)",
            family_params={"fallback": "brake"},
            loss="distance_shortfall",
            loss_params=_SHORTFALL,
            rule_params=_CC_RULE,
        ),
        PlanarMethod(
            "acp_mpc",
            "acp_mpc",
            "ACP regions per plan step (ACI, alpha = 0.2, gamma = 0.05, as published)",
            loss="plan_miscoverage",
            rule="aci",
            rule_params={"alpha": 0.2, "gamma": 0.05},
        ),
        PlanarMethod(
            "ecp_mpc",
            "ecp_mpc",
            "egocentric conformal regions (ACI, alpha = 0.1, gamma = 0.02, 15 calibration "
            "times, as published)",
            family_params={"calibration_size": 15},
            loss="ego_miscoverage",
            rule="aci",
            rule_params={"alpha": 0.1, "gamma": 0.02},
        ),
        PlanarMethod(
            "fcp_mpc",
            "fcp_mpc",
            "conformalized distance fields, hard constraint, calibrated on the recording "
            "outside the scenario's window, with the published online adaptation of the "
            "radii (step 0.05) at a target field-violation rate of 0.5 (chosen on the "
            "dense suite's dev part among 0.1, 0.3, 0.5)",
            family_params={"calibration__slack": "upper", "continuous": True},
            loss="field_miscoverage",
            rule_params={**_FCP_RULE, "epsilon": 0.5},
            calibration="held_out",
        ),
        # ---- the published definitions (the published table's rows)
        PlanarMethod(
            "acp_mpc_pub",
            "acp_mpc",
            "ACP-MPC as published: ACI alpha = 0.2, gamma = 0.05, velocity 0 when no plan is "
            "safe, step ends checked",
            family_params=PUBLISHED_SEARCH,
            loss="plan_miscoverage",
            rule="aci",
            rule_params={"alpha": 0.2, "gamma": 0.05},
            definition="published",
            published="ACP-MPC",
        ),
        PlanarMethod(
            "cc_mpc_pub",
            "soft_mpc",
            "CC-MPC as published: no safe distance, a reward of weight -lambda per metre "
            "of predicted distance, fixed-eta rule on -d_min (eps = -2 m, eta = 5000)",
            family_params={"continuous": False},
            loss="negative_distance",
            rule_params={"epsilon": -2.0, "eta": 5000.0, "lambda_init": -1.0, "lambda_max": -0.01},
            definition="published",
            published="CC-MPC",
        ),
        PlanarMethod(
            "ecp_mpc_pub",
            "ecp_mpc",
            "ECP-MPC as published: ACI alpha = 0.1, gamma = 0.02, 15 calibration times, "
            "velocity 0 when no plan is safe, step ends checked",
            family_params={**PUBLISHED_SEARCH, "calibration_size": 15},
            loss="ego_miscoverage",
            rule="aci",
            rule_params={"alpha": 0.1, "gamma": 0.02},
            definition="published",
            published="ECP-MPC",
        ),
        PlanarMethod(
            "fcp_mpc_hard_pub",
            "fcp_mpc",
            "FCP-MPC (hard) as published: envelopes calibrated offline on the recording "
            "(alpha = 0.1), not adapted, velocity 0 when no plan is safe, step ends checked",
            False,
            family_params={**PUBLISHED_SEARCH, "calibration__slack": "published"},
            loss="field_miscoverage",
            calibration="recording",
            definition="published",
            published="FCP-MPC (hard)",
        ),
        PlanarMethod(
            "fcp_mpc_soft_pub",
            "fcp_mpc",
            "FCP-MPC (soft) as published: the same envelopes as a penalty (w_safety = 100), "
            "not adapted",
            False,
            family_params={
                **PUBLISHED_SEARCH,
                "calibration__slack": "published",
                "constraint__mode": "soft",
                "constraint__w_safety": 100.0,
            },
            loss="field_miscoverage",
            calibration="recording",
            definition="published",
            published="FCP-MPC (soft)",
        ),
    )
}


#: A shifted predictor on the protocol: ``<predictor>@delay-<seconds>s`` (the forecast of
#: data that old used as current, :class:`~conformal_control.predictors.shift.DelayedPredictor`;
#: a whole number of 0.4 s samples, at most 7).
SHIFT_SEPARATOR = "@"


def _predictor(name: str, task: PlanarTask, data_root: str | Path | None) -> TimedPredictor:
    from ...core import registry

    if SHIFT_SEPARATOR in name:
        import re

        from ...predictors.shift import DelayedPredictor

        base, shift = name.split(SHIFT_SEPARATOR, 1)
        match = re.fullmatch(r"delay-([0-9]*\.?[0-9]+)s", shift)
        if match is None:
            raise ValueError(
                f"unknown planar predictor shift {shift!r} in {name!r}: use "
                f"<predictor>{SHIFT_SEPARATOR}delay-<seconds>s"
            )
        inner = _predictor(base, task, data_root).predictor
        return TimedPredictor(DelayedPredictor(inner, delay_s=float(match.group(1))))
    if name == "oracle":
        return TimedPredictor(RecordingOracle(recording(task, data_root)))
    if name == "recorded":
        inner = registry.create("predictor", "recorded", **_recorded_params(task, data_root))
    else:
        inner = registry.create("predictor", name)
    return TimedPredictor(inner)


class RecordingOracle(Predictor):
    """The recording's true future as the prediction (the oracle rows).

    A query's ``frame`` is the recording's sample (frame / 10); the forecast of a
    pedestrian is its recorded positions at the next ``horizon`` samples, NaN where it is
    not in the recording (the families hold the last known position there, counted).

    Parameters
    ----------
    recording : PlanarRecording
        The recording the protocol replays.
    """

    def __init__(self, recording: PlanarRecording) -> None:
        self.recording = recording

    def reset(self) -> None:
        rec = self.recording
        self._column = {int(pid): c for c, pid in enumerate(rec.ids.tolist())}

    def predict(self, query: PredictionQuery) -> Forecast:
        if not hasattr(self, "_column"):
            self.reset()
        rec = self.recording
        i = int(query.frame) - rec.first
        cols = np.array([self._column[int(pid)] for pid in query.ids], dtype=np.int64)
        out = np.full((cols.size, int(query.horizon), 2), np.nan)
        for k in range(int(query.horizon)):
            out[:, k] = rec.at(i + k + 1, cols)
        return Forecast(out)


class TimedPredictor(Predictor):
    """A predictor that measures its own time (``seconds_``): the protocol's controller
    time leaves the predictions out (the published runs read them from files).

    Parameters
    ----------
    predictor : Predictor
        The predictor timed.
    """

    def __init__(self, predictor: Predictor) -> None:
        self.predictor = predictor

    def reset(self) -> None:
        self.predictor.reset()
        self.seconds_ = 0.0

    def predict(self, query: PredictionQuery) -> Forecast:
        t0 = time.perf_counter()
        try:
            return self.predictor.predict(query)
        finally:
            self.seconds_ += time.perf_counter() - t0


def _recorded_params(task: PlanarTask, data_root: str | Path | None) -> dict[str, Any]:
    """Arguments of the ``recorded`` predictor for a task's Trajectron++ file."""
    from ...data.paths import external_root

    path = external_root(data_root) / "trajectron-ethucy" / f"{task.dataset}.csv.gz"
    return {"path": str(path), "step_s": STEP_S, "frames_per_step": float(FRAMES_PER_STEP)}


RECORDED_DATASETS = ("eth", "hotel", "zara1")


def build_method(
    method: PlanarMethod, predictor: Any, seed: int = 0, envelope: Any = None
) -> tuple[Any, Any, Any, Any]:
    """``(family, plant, loss, rule)`` of a method on the protocol's robot.

    Parameters
    ----------
    method : PlanarMethod
        The method.
    predictor : Predictor
        The predictor its family plans with.
    seed : int
        The family's random state.
    envelope : FunctionalEnvelope, optional
        An ``fcp_mpc`` method's calibrated envelopes (:func:`scenario_envelope`).
    """
    from ...core import registry
    from ...families.cbf.barriers import APFBarrier
    from ...families.cbf.constraint import ConformalConstraint
    from ...families.cbf.controller import ConformalCBFController
    from ...families.cbf.dynamics import Unicycle, UnicycleLookahead
    from ...families.cbf.filters.exact2d import Exact2DSafetyFilter
    from ...families.cbf.reference import AttractiveField

    limits = {
        "v_min": ROBOT["v_min_mps"],
        "v_max": ROBOT["v_max_mps"],
        "omega_max": ROBOT["omega_max_radps"],
        "integrator": "euler",
    }
    v_max = float(ROBOT["v_max_mps"])
    fp = dict(method.family_params)
    constraint = None
    plant: Unicycle
    if method.family == "cbf":
        p = {**CBF_PARAMS, **fp}
        plant = UnicycleLookahead(**limits, lookahead=p["lookahead"])
        barrier = APFBarrier(K_rep=p["K_rep"], rho0=p["rho0"], d_c=COLLISION_M + p["lookahead"])
        constraint = ConformalConstraint(barrier, a=p["a"])
        family: Any = ConformalCBFController(
            predictor,
            constraint,
            Exact2DSafetyFilter(v_max=v_max),
            AttractiveField(K_att=p["K_att"], v_max=v_max),
            substeps=1,
        )
    else:
        plant = Unicycle(**limits)
        params = {**MPC_PARAMS, "d_c": COLLISION_M, "substeps": 1, "random_state": seed, **fp}
        if envelope is not None:
            params["envelope"] = envelope
        family = registry.create(
            "family", method.family, predictor=predictor, dynamics=plant, **params
        )
    loss_params = dict(method.loss_params)
    if method.loss == "cbf_gap":
        loss_params.setdefault("constraint", constraint)
    loss = registry.create("loss", method.loss, **loss_params)
    rule = registry.create("rule", method.rule, **dict(method.rule_params))
    return family, plant, loss, rule


# ------------------------------------------------------------------------------ episodes
@dataclass
class ScenarioResult:
    """One scenario of the protocol: per-step log and metrics.

    Attributes
    ----------
    dataset, method, predictor : str
    start_timestep : int
    steps : list of dict
        One entry per step: ``count``, ``timestep``, ``x``, ``y``, ``heading``,
        ``recorded``, ``collision``, ``infeasible``, ``status``, ``lambda``, ``d_min``,
        ``ctrl_ms``.
    goal_step : int or None
        Step count at which the goal was reached.
    ended : str
        ``"goal"``, ``"max_steps"`` or ``"data"``.
    stats : dict
        The family's counters.
    """

    dataset: str
    method: str
    predictor: str
    start_timestep: int
    max_steps: int
    steps: list[dict[str, Any]] = field(default_factory=list)
    goal_step: int | None = None
    ended: str = "max_steps"
    stats: dict[str, Any] = field(default_factory=dict)

    def metrics(self) -> dict[str, Any]:
        """The protocol's metrics of this scenario (:func:`scenario_metrics`)."""
        return scenario_metrics(self.steps, self.goal_step, self.max_steps)


def scenario_metrics(
    steps: Sequence[Mapping[str, Any]], goal_step: int | None, max_steps: int
) -> dict[str, Any]:
    """Collision rate, infeasible rate, steps to goal and controller time of a scenario,
    from its per-step log (see :data:`METRICS`)."""
    rec = [s for s in steps if s["recorded"]]
    n = len(rec)
    timed = [s["ctrl_ms"] for s in steps if s.get("ctrl_ms") is not None]
    return {
        "n_recorded": n,
        "collision_rate": sum(bool(s["collision"]) for s in rec) / n if n else math.nan,
        "infeasible_rate": sum(bool(s["infeasible"]) for s in rec) / n if n else math.nan,
        "steps_to_goal": float(min(goal_step, max_steps) if goal_step is not None else max_steps),
        "reached": goal_step is not None,
        "ctrl_time_ms": float(np.mean(timed)) if timed else math.nan,
    }


def dataset_metrics(scenarios: Sequence[Mapping[str, Any]], max_steps: int) -> dict[str, Any]:
    """A dataset's figures from its scenarios' metrics (scenarios without a recorded step
    are left out)."""
    valid = [m for m in scenarios if m["n_recorded"] > 0]

    def mean(key: str) -> float:
        vals = [float(m[key]) for m in valid if math.isfinite(float(m[key]))]
        return float(np.mean(vals)) if vals else math.nan

    steps = mean("steps_to_goal")
    return {
        "n_scenarios": len(valid),
        "n_reached": sum(bool(m["reached"]) for m in valid),
        "collision_rate": mean("collision_rate"),
        "infeasible_rate": mean("infeasible_rate"),
        "steps_to_goal": steps,
        "timeout": bool(math.isfinite(steps) and steps >= max_steps - 0.5),
        "ctrl_time_ms": mean("ctrl_time_ms"),
    }


def run_scenario(
    task: PlanarTask,
    start_timestep: int,
    method: PlanarMethod,
    predictor: str = "constant_velocity",
    *,
    data_root: str | Path | None = None,
    seed: int = 0,
) -> ScenarioResult:
    """Run one scenario of the protocol with one of our methods (see the module docstring).

    The family runs through :class:`~conformal_control.core.loop.ConformalStepper`, one interval
    per step: at each step it receives the pedestrians with a history (their last
    ``HISTORY_SAMPLES`` positions), decides once (after the warm-up), and the interval is
    scored on the pedestrians' positions at the next time step.

    Parameters
    ----------
    task : PlanarTask
        The dataset's protocol (start pose, goal, steps, ...).
    start_timestep : int
        The recording's time step the scenario starts at.
    method : PlanarMethod
        The method (family, loss, rule).
    predictor : str
        ``recorded`` or a registered predictor.
    data_root : str or Path, optional
        The data folder.
    seed : int
        The family's random state.
    """
    steps = _scenario(task, start_timestep, method, predictor, data_root=data_root, seed=seed)
    try:
        next(steps)
        while True:
            steps.send(0.0)
    except StopIteration as done:
        return cast(ScenarioResult, done.value)


def run_scenarios(
    task: PlanarTask,
    start_timesteps: Sequence[int],
    method: PlanarMethod,
    predictor: str = "constant_velocity",
    *,
    data_root: str | Path | None = None,
    seed: int = 0,
) -> list[ScenarioResult]:
    """:func:`run_scenario` of several start times of a task, in lockstep: the scenarios
    advance together from one decision to the next, and a sampling-MPC family's plans of
    every scenario at a decision are evaluated in one compiled call
    (:func:`~conformal_control.families.mpc.batch.plan_all`). The results equal
    :func:`run_scenario`'s one by one (``tests/families/mpc/test_batch.py``), except the measured
    times: a scenario's controller time includes its share (an equal part) of the joint
    evaluation. Not faster than one at a time at the protocol's size (see
    :mod:`conformal_control.families.mpc.batch`), so :func:`run_planar` does not use it.

    Parameters
    ----------
    task : PlanarTask
        The dataset's protocol.
    start_timesteps : sequence of int
        The scenarios' start time steps.
    method : PlanarMethod
        The method (family, loss, rule).
    predictor : str
        ``recorded`` or a registered predictor.
    data_root : str or Path, optional
        The data folder.
    seed : int
        Every family's random state.

    Returns
    -------
    list of ScenarioResult
        One per start time step, in order.
    """
    from ...families.mpc.batch import plan_all

    runs = [
        _scenario(task, s, method, predictor, data_root=data_root, seed=seed)
        for s in start_timesteps
    ]
    out: list[ScenarioResult | None] = [None] * len(runs)
    waiting: dict[int, tuple[Any, Any, float]] = {}

    def advance(i: int, share: float | None) -> None:
        try:
            waiting[i] = next(runs[i]) if share is None else runs[i].send(share)
        except StopIteration as done:
            waiting.pop(i, None)
            out[i] = cast(ScenarioResult, done.value)

    for i in range(len(runs)):
        advance(i, None)
    while waiting:
        live = sorted(waiting)
        t0 = time.perf_counter()
        plan_all([waiting[i] for i in live])
        share = (time.perf_counter() - t0) / len(live)
        for i in live:
            advance(i, share)
    return [cast(ScenarioResult, r) for r in out]


def _scenario(
    task: PlanarTask,
    start_timestep: int,
    method: PlanarMethod,
    predictor: str = "constant_velocity",
    *,
    data_root: str | Path | None = None,
    seed: int = 0,
) -> Generator[tuple[Any, Any, float], float, ScenarioResult]:
    """One scenario as a generator: before each decision it yields ``(family, state,
    lambda)`` and receives the seconds of joint work done for it meanwhile (its share of
    :func:`~conformal_control.families.mpc.batch.plan_all`, counted in its controller time); it
    returns the :class:`ScenarioResult`."""
    from ...core.loop import ConformalStepper
    from ...families.cbf.controller import ControlState
    from ...families.cbf.loss import CBFTruth

    rec = recording(task, data_root)
    predictor = method.predictor or predictor
    pred = _predictor(predictor, task, data_root)
    envelope = None
    if method.calibration is not None:
        envelope = scenario_envelope(task, start_timestep, method, predictor, data_root)
    family, plant, loss, rule = build_method(method, pred, seed, envelope)
    stepper = ConformalStepper(family, loss, rule, learn=method.learn)
    stepper.start()
    x = plant.initial_state(np.array(task.init_pose[:2]), task.init_pose[2])
    goal = np.array(task.goal, dtype=float)
    out = ScenarioResult(task.dataset, method.name, predictor, int(start_timestep), task.max_steps)
    ts, count = int(start_timestep), 0
    t0_ts = ts
    while count < task.max_steps:
        i = rec.sample(ts, task.frame_offset)
        if i >= rec.positions.shape[0]:
            out.ended = "data"
            break
        cols = rec.pedestrians(i)
        if cols.size == 0:  # no pedestrian with a history: not a step of the protocol
            ts += 1
            continue
        t = (ts - t0_ts) * STEP_S
        current = rec.at(i, cols)
        query = PredictionQuery(
            ids=rec.ids[cols],
            history=rec.history(i, cols),
            dt=STEP_S,
            horizon=1,
            t=t,
            frame=ts + task.frame_offset // FRAMES_PER_STEP,  # sample index (frame / 10)
            scene=task.dataset,
        )
        d_min = float(np.hypot(*(current - x[:2]).T).min())
        entry: dict[str, Any] = {
            "count": count,
            "timestep": ts,
            "x": float(x[0]),
            "y": float(x[1]),
            "heading": float(x[4]),
            "recorded": False,
            "collision": False,
            "infeasible": False,
            "status": "warm_up",
            "lambda": stepper.lam,
            "d_min": d_min,
            "ctrl_ms": None,
        }
        reached = count >= WARM_UP_STEPS and math.hypot(*(x[:2] - goal)) <= GOAL_TOLERANCE_M
        if reached:
            out.goal_step = count
            out.ended = "goal"
            entry["status"] = "goal"
            out.steps.append(entry)
            break
        c0 = time.perf_counter()
        p0 = pred.seconds_
        stepper.begin_interval(query)
        cmd = np.zeros(2)
        if count >= WARM_UP_STEPS:
            st = ControlState(x=x.copy(), t=t, step=0, goal=goal)
            before = time.perf_counter() - c0
            shared = yield family, st, stepper.lam
            c1 = time.perf_counter()
            cmd = np.asarray(stepper.decide(st), dtype=float)
            spent = before + shared + (time.perf_counter() - c1)
            entry["ctrl_ms"] = (spent - (pred.seconds_ - p0)) * 1e3
            entry["pred_ms"] = (pred.seconds_ - p0) * 1e3
            entry["recorded"] = True
            entry["collision"] = d_min < COLLISION_M
        nxt = rec.at(i + 1, cols)
        stepper.end_interval(
            CBFTruth(samples=np.stack([current, nxt], axis=1), dt=STEP_S, substeps=1)
        )
        if entry["recorded"]:  # the decision's status: the record the loss was given
            status = stepper.record_.status[-1]
            entry["status"] = status
            entry["infeasible"] = status not in ("optimal", "unconstrained")
        x = plant.step(x, cmd, STEP_S)
        out.steps.append(entry)
        ts += 1
        count += 1
    out.stats = {k: float(v) for k, v in family.stats().items()}
    out.stats["lambda_final"] = float(stepper.lam)
    return out


# ------------------------------------------------------------------------------ fcp_mpc
_PREDICTIONS: dict[tuple[str, ...], Any] = {}
_ENVELOPES: dict[tuple[Any, ...], Any] = {}


def method_calibration(method: PlanarMethod) -> Any:
    """The :class:`~conformal_control.families.mpc.fcp.FieldCalibration` of an ``fcp_mpc`` method
    (its ``calibration__*`` parameters over the published defaults)."""
    from ...families.mpc.fcp import FieldCalibration

    pre = "calibration__"
    given = {k[len(pre) :]: v for k, v in method.family_params.items() if k.startswith(pre)}
    return FieldCalibration(**given)


def scenario_envelope(
    task: PlanarTask,
    start_timestep: int,
    method: PlanarMethod,
    predictor: str,
    data_root: str | Path | None = None,
) -> Any:
    """The envelopes an ``fcp_mpc`` method plans with in a scenario, calibrated offline on
    the recording with the scenario's predictor
    (:mod:`~conformal_control.experiments.bench.planar_fcp`;
    cached in the process: the seeds of a scenario share them).

    Parameters
    ----------
    task : PlanarTask
        The dataset's protocol.
    start_timestep : int
        The scenario's start.
    method : PlanarMethod
        An ``fcp_mpc`` method with a ``calibration``.
    predictor : str
        The predictor the scenario runs with.
    data_root : str or Path, optional
        The data folder.
    """
    from .planar_fcp import calibrate, predictions_on

    if method.calibration is None:
        raise ValueError(f"method {method.name!r} is calibrated online, not offline")
    settings = method_calibration(method)
    rec = recording(task, data_root)
    key = (task.dataset, task.recording, predictor, str(data_root))
    if key not in _PREDICTIONS:
        horizon = int(MPC_PARAMS["sampling__horizon"])

        def frame_of(i: int) -> int:
            return i + rec.first  # the query's frame: the recording's sample index

        _PREDICTIONS.clear()  # one recording's at a time (they hold every forecast)
        _PREDICTIONS[key] = predictions_on(
            rec, _predictor(predictor, task, data_root), horizon, STEP_S, frame_of, task.dataset
        )
    from .planar_fcp import scenario_samples

    horizon = int(MPC_PARAMS["sampling__horizon"])
    last_sample = rec.positions.shape[0] - 1
    if task.part is None:  # the scenario's own grid; held out: its window
        first = rec.sample(start_timestep, task.frame_offset)
        span = (first, min(first + min(int(task.max_steps), 200) - 1, last_sample))
        lo, hi = scenario_samples(rec, first, task.max_steps)
        window = (lo - horizon, hi)
    else:  # the part's grid, one calibration for its scenarios; held out: the other part
        span = (
            rec.sample(task.part[0], task.frame_offset),
            rec.sample(task.part[1], task.frame_offset),
        )
        span = (max(span[0], 0), min(span[1], last_sample))
        window = (span[0] - horizon, span[1])
    exclude = window if method.calibration == "held_out" else None
    cal = tuple(sorted(settings.get_params().items()))
    ekey = (*key, span, exclude, cal)
    if ekey not in _ENVELOPES:
        if len(_ENVELOPES) >= 6:
            _ENVELOPES.pop(next(iter(_ENVELOPES)))
        _ENVELOPES[ekey] = calibrate(
            rec, _PREDICTIONS[key], span, [task.init_pose[:2], task.goal], exclude, settings
        )
    return _ENVELOPES[ekey]


# ------------------------------------------------------------------------------ suite
def predictors_for(dataset: str, predictors: Sequence[str]) -> list[str]:
    """The predictors run on a dataset: ``recorded`` (and its shifts) only where its file
    exists."""
    return [
        p
        for p in predictors
        if p.split(SHIFT_SEPARATOR)[0] != "recorded" or dataset in RECORDED_DATASETS
    ]


def run_planar(
    out: str | Path,
    *,
    methods: Iterable[str] | None = None,
    predictors: Sequence[str] = ("recorded", "constant_velocity"),
    datasets: Iterable[str] | None = None,
    data_root: str | Path | None = None,
    seed: int = 0,
    seeds: Sequence[int] | None = None,
    tasks: Mapping[str, PlanarTask] | None = None,
    suite: str = SUITE,
    progress: Callable[[str], None] | None = None,
    resume: bool = True,
) -> list[dict[str, Any]]:
    """Run the suite: every dataset's scenarios x methods x predictors x seeds.

    Writes ``OUT/config.json`` (the protocol, the methods, the predictors, the seeds) and
    ``OUT/rows.jsonl`` (one row per scenario and seed: its metrics, the family's counters,
    the per-step log); returns the rows. A method with its own predictor (the oracle rows)
    runs once per dataset, under that predictor's name.

    Resumable, like ``bench run``: the rows a previous run into ``OUT`` finished
    (``rows.jsonl``, or ``rows.jsonl.part`` of a stopped run) are kept and not run again
    when that run's ``config.json`` has the same protocol and the same definition of the
    row's method (:func:`reusable_rows`); every other row runs.

    Parameters
    ----------
    out : str or Path
        The output folder (created).
    methods : iterable of str, optional
        Planar methods (None: all of :data:`PLANAR_METHODS`).
    predictors : sequence of str
        Predictors; ``recorded`` runs only on the datasets that have its file.
    datasets : iterable of str, optional
        ``eth``, ``hotel``, ``univ``, ``zara1``, ``zara2`` (None: all).
    data_root : str or Path, optional
        The data folder.
    seed : int
        The families' random state (with ``seeds`` None).
    seeds : sequence of int, optional
        Several random states: every scenario runs once per seed.
    tasks : mapping, optional
        The datasets' tasks (default :data:`TASKS`, the published 13 scenarios; the dense
        suite's, :mod:`~conformal_control.experiments.bench.planar_dense`).
    suite : str
        The suite's name (``config.json``).
    progress : callable, optional
        Called with one line per scenario run (and one saying how many rows were kept).
    resume : bool
        Keep the rows a previous run into ``OUT`` finished (default); False runs all.

    Raises
    ------
    ValueError
        For an unknown method or dataset (the message lists the known ones), or no seed.
    """
    task_map = dict(TASKS if tasks is None else tasks)
    names = list(methods or PLANAR_METHODS)
    unknown = [m for m in names if m not in PLANAR_METHODS]
    if unknown:
        raise ValueError(
            f"unknown planar method(s) {', '.join(unknown)}; known: {', '.join(PLANAR_METHODS)}"
        )
    sets = list(datasets or task_map)
    bad = [d for d in sets if d not in task_map]
    if bad:
        raise ValueError(f"unknown dataset(s) {', '.join(bad)}; known: {', '.join(task_map)}")
    seed_list = [int(seed)] if seeds is None else [int(s) for s in seeds]
    if not seed_list:
        raise ValueError("give at least one seed")
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    warm_up_kernels()
    config = {
        "suite": suite,
        "protocol": protocol_dict(task_map),
        "methods": [PLANAR_METHODS[m].as_dict() for m in names],
        "predictors": list(predictors),
        "datasets": sets,
        "seed": seed_list[0],
        "seeds": seed_list,
    }
    kept = reusable_rows(folder, config) if resume else {}
    if kept and progress is not None:
        progress(f"resuming: {len(kept)} rows of a previous run into {folder} kept")
    (folder / "config.json").write_text(json.dumps(config, indent=1, default=str) + "\n")
    rows = []
    tmp = folder / "rows.jsonl.part"
    with tmp.open("w") as fh:
        for ds in sets:
            task = task_map[ds]
            for pred in predictors_for(ds, predictors):
                for name in names:
                    method = PLANAR_METHODS[name]
                    if method.predictor is not None and pred != predictors_for(ds, predictors)[0]:
                        continue  # its own predictor: once per dataset
                    label = method.predictor or pred
                    for sd in seed_list:
                        for start in task.start_timesteps:
                            done = kept.get((ds, name, label, sd, int(start)))
                            if done is not None:  # finished by a previous run
                                rows.append(done)
                                fh.write(json.dumps(done, default=float) + "\n")
                                continue
                            res = run_scenario(
                                task, start, method, pred, data_root=data_root, seed=sd
                            )
                            row = {
                                "dataset": ds,
                                "method": name,
                                "predictor": label,
                                "seed": sd,
                                "start_timestep": start,
                                "ended": res.ended,
                                "goal_step": res.goal_step,
                                **res.metrics(),
                                "stats": res.stats,
                                "steps": res.steps,
                            }
                            rows.append(row)
                            fh.write(json.dumps(row, default=float) + "\n")
                            fh.flush()
                            if progress is not None:
                                m = res.metrics()
                                progress(
                                    f"{ds} {start} {name} ({label}, seed {sd}): collision "
                                    f"{m['collision_rate']:.3f}, infeasible "
                                    f"{m['infeasible_rate']:.3f}, steps "
                                    f"{m['steps_to_goal']:.0f}, {m['ctrl_time_ms']:.2f} ms"
                                )
    tmp.replace(folder / "rows.jsonl")
    return rows


def reusable_rows(
    folder: Path, config: Mapping[str, Any]
) -> dict[tuple[str, str, str, int, int], dict[str, Any]]:
    """The rows a previous :func:`run_planar` into ``folder`` finished that a run of
    ``config`` would produce alike, by ``(dataset, method, predictor, seed, start)``.

    Kept only when the previous ``config.json`` has the same suite and protocol and the
    row's method the same definition (its :meth:`PlanarMethod.as_dict`); rows of
    ``rows.jsonl`` (a finished run) and of ``rows.jsonl.part`` (a stopped one; a last line
    cut off mid-write is dropped) count.

    Parameters
    ----------
    folder : Path
        The output folder.
    config : mapping
        The new run's ``config.json`` content.
    """
    cfg = folder / "config.json"
    if not cfg.is_file():
        return {}
    try:
        old = json.loads(cfg.read_text())
    except ValueError:
        return {}

    def canon(v: Any) -> str:
        return json.dumps(v, sort_keys=True, default=str)

    if old.get("suite") != config["suite"] or canon(old.get("protocol")) != canon(
        json.loads(json.dumps(config["protocol"], default=str))
    ):
        return {}
    new_defs = {m["name"]: canon(m) for m in json.loads(json.dumps(config["methods"], default=str))}
    same = {
        m["name"]
        for m in old.get("methods", [])
        if isinstance(m, dict) and new_defs.get(m.get("name")) == canon(m)
    }
    kept: dict[tuple[str, str, str, int, int], dict[str, Any]] = {}
    for name in ("rows.jsonl", "rows.jsonl.part"):
        path = folder / name
        if not path.is_file():
            continue
        for line in path.read_text().splitlines():
            try:
                row = json.loads(line)
            except ValueError:  # cut off mid-write
                continue
            if isinstance(row, dict) and row.get("method") in same:
                key = (
                    str(row["dataset"]),
                    str(row["method"]),
                    str(row["predictor"]),
                    int(row["seed"]),
                    int(row["start_timestep"]),
                )
                kept[key] = row
    return kept


def warm_up_kernels() -> None:
    """Compile (or load from numba's cache) the MPC's kernels once, so that the first
    scenario's controller time does not include it."""
    from ...core.jit import compile_now
    from ...families.cbf.dynamics import Unicycle
    from ...families.mpc.kernels import evaluate

    compile_now()  # a suite of episodes: compiled (see conformal_control.core.jit)
    cmds = np.zeros((2, 3, 2))
    pos = Unicycle().rollout(np.zeros(5), cmds, STEP_S)[..., :2]
    evaluate(
        pos,
        cmds,
        np.zeros(2),
        np.ones((1, 3, 2)),
        np.ones((1, 2)),
        np.ones(3),
        np.zeros(2),
        (1.0, 1.0, 0.0, 0.0),
        np.zeros(2),
        True,
    )


def read_planar_rows(folder: str | Path) -> list[dict[str, Any]]:
    """The rows a :func:`run_planar` folder holds."""
    path = Path(folder) / "rows.jsonl"
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: not a `bench run --suite {SUITE}` folder")
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def is_planar_folder(folder: str | Path) -> bool:
    cfg = Path(folder) / "config.json"
    if not cfg.is_file():
        return False
    try:
        return bool(json.loads(cfg.read_text()).get("suite") == SUITE)
    except (ValueError, AttributeError):
        return False


def protocol_dict(tasks: Mapping[str, PlanarTask] | None = None) -> dict[str, Any]:
    """The protocol as data (written beside every result), with ``tasks`` (default
    :data:`TASKS`)."""
    task_map = TASKS if tasks is None else tasks
    return {
        "time_step_s": STEP_S,
        "frames_per_step": FRAMES_PER_STEP,
        "robot": dict(ROBOT),
        "pedestrian_radius_m": PED_RADIUS_M,
        "collision_distance_m": COLLISION_M,
        "warm_up_steps": WARM_UP_STEPS,
        "goal_tolerance_m": GOAL_TOLERANCE_M,
        "datasets": {
            k: {
                "recording": t.recording,
                "start_timesteps": list(t.start_timesteps),
                "frame_offset": t.frame_offset,
                "max_steps": t.max_steps,
                "init_pose": list(t.init_pose),
                "goal": list(t.goal),
                "part": None if t.part is None else list(t.part),
            }
            for k, t in task_map.items()
        },
        "metrics": dict(METRICS),
    }


def _fmt(v: Any, nd: int = 3) -> str:
    if v is None:
        return "N/A"
    if isinstance(v, str):
        return v
    return "--" if not math.isfinite(float(v)) else f"{float(v):.{nd}f}"


def seed_summary(rows: Sequence[Mapping[str, Any]], max_steps: int) -> dict[str, Any]:
    """A method's figures on a dataset over seeds: :func:`dataset_metrics` per seed, their
    mean, and each metric's smallest and largest seed value (``<metric>_min``,
    ``<metric>_max``); ``n_reached`` and ``n_scenarios`` summed over seeds."""
    by_seed: dict[int, list[Mapping[str, Any]]] = {}
    for r in rows:
        by_seed.setdefault(int(r.get("seed", 0)), []).append(r)
    per = [dataset_metrics(rs, max_steps) for _, rs in sorted(by_seed.items())]
    out: dict[str, Any] = {"n_seeds": len(per)}
    for key in ("collision_rate", "infeasible_rate", "steps_to_goal", "ctrl_time_ms"):
        vals = [float(m[key]) for m in per if math.isfinite(float(m[key]))]
        out[key] = float(np.mean(vals)) if vals else math.nan
        out[f"{key}_min"] = min(vals) if vals else math.nan
        out[f"{key}_max"] = max(vals) if vals else math.nan
    out["n_reached"] = sum(int(m["n_reached"]) for m in per)
    out["n_scenarios"] = sum(int(m["n_scenarios"]) for m in per)
    steps = out["steps_to_goal"]
    out["timeout"] = bool(math.isfinite(steps) and steps >= max_steps - 0.5)
    return out


def _spread(m: Mapping[str, Any], key: str, nd: int) -> str:
    """``mean`` or, over several seeds, ``mean (min-max)``."""
    text = _fmt(m[key], nd)
    if m.get("n_seeds", 1) > 1 and math.isfinite(float(m[key])):
        text += f" ({_fmt(m[f'{key}_min'], nd)}-{_fmt(m[f'{key}_max'], nd)})"
    return text


def planar_table(
    rows: Sequence[Mapping[str, Any]], tasks: Mapping[str, PlanarTask] | None = None
) -> tuple[str, list[dict[str, Any]]]:
    """Markdown table of our rows beside the published ones, and its rows as dicts.

    Per dataset: the published table's rows, then ours (method, predictor) with collision
    rate, goals reached (over scenarios and seeds), infeasible rate, steps to goal
    ("timeout" when no scenario reached the goal) and ms per step; over several seeds each
    figure is the seeds' mean with their range. ``definition`` says whether a row follows
    a published method's definition or is ours.
    """
    task_map = TASKS if tasks is None else tasks
    lines = [
        "| dataset | method | definition | predictor | collision rate | reached | "
        "infeasible rate | steps to goal | ms/step | seeds | source |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    table: list[dict[str, Any]] = []
    for ds, task in task_map.items():
        for name, (col, inf, steps, ms) in PUBLISHED.get(ds, {}).items():
            table.append(
                {
                    "dataset": ds,
                    "method": name,
                    "definition": "published",
                    "predictor": "Trajectron++",
                    "collision_rate": col,
                    "infeasible_rate": inf,
                    "steps_to_goal": steps,
                    "reached": None,
                    "ctrl_time_ms": ms,
                    "source": "published",
                }
            )
            lines.append(
                f"| {ds} | {name} | published | Trajectron++ | {_fmt(col)} | | {_fmt(inf)} | "
                f"{steps if isinstance(steps, str) else f'{steps:.1f}'} | {ms:.2f} | | published |"
            )
        groups: dict[tuple[str, str], list[Mapping[str, Any]]] = {}
        for r in rows:
            if r["dataset"] == ds:
                groups.setdefault((str(r["method"]), str(r["predictor"])), []).append(r)
        for (method, pred), rs in groups.items():
            m = seed_summary(rs, task.max_steps)
            known = PLANAR_METHODS.get(method)
            definition = known.definition if known is not None else "ours"
            label = f"{method} ({known.published})" if known and known.published else method
            steps_s = "timeout" if m["timeout"] else _spread(m, "steps_to_goal", 1)
            table.append(
                {
                    "dataset": ds,
                    "method": method,
                    "definition": definition,
                    "predictor": pred,
                    **m,
                    "source": "ours",
                }
            )
            lines.append(
                f"| {ds} | **{label}** | {definition} | {pred} | "
                f"{_spread(m, 'collision_rate', 3)} | {m['n_reached']}/{m['n_scenarios']} | "
                f"{_spread(m, 'infeasible_rate', 3)} | {steps_s} | "
                f"{_fmt(m['ctrl_time_ms'], 2)} | {m['n_seeds']} | ours |"
            )
    return "\n".join(lines) + "\n", table


# ------------------------------------------------------------------------------ commands
def run_command(
    out: str,
    methods: str | None,
    predictor: str | None,
    data_root: str | None,
    datasets: str | None = None,
    seeds: str | None = None,
) -> int:
    """``bench run --suite fcp-planar``: run, write the folder and print the table.

    Parameters
    ----------
    out : str
        The output folder.
    methods : str, optional
        Comma-separated planar methods (None: all).
    predictor : str, optional
        Comma-separated predictors (None: ``recorded,constant_velocity``; ``recorded`` is
        left out when not installed).
    data_root : str, optional
        The data folder.
    datasets : str, optional
        Comma-separated datasets (None: all five).
    seeds : str, optional
        Comma-separated random states (None: 0).
    """
    from ...core import registry

    try:
        seed_list = [int(v) for v in (seeds or "0").split(",") if v.strip()]
    except ValueError:
        raise ValueError(f"--seeds takes comma-separated integers, got {seeds!r}") from None

    preds = [p.strip() for p in (predictor or "recorded,constant_velocity").split(",") if p]
    if "recorded" in preds and "recorded" not in registry.names("predictor"):
        print("the `recorded` predictor is not installed: running without it")
        preds = [p for p in preds if p != "recorded"]
    rows = run_planar(
        out,
        methods=[m.strip() for m in methods.split(",") if m.strip()] if methods else None,
        predictors=preds,
        datasets=[d.strip() for d in datasets.split(",") if d.strip()] if datasets else None,
        data_root=data_root,
        seeds=seed_list,
        progress=lambda line: print(line, flush=True),
    )
    write_planar_report(rows, Path(out) / "report")
    print(planar_table(rows)[0])
    return 0


def write_planar_report(rows: Sequence[Mapping[str, Any]], out: str | Path) -> dict[str, Path]:
    """``planar.md`` (our rows beside the published ones, the metric definitions, the
    differences) and ``planar.csv``."""
    import csv

    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    text, table = planar_table(rows)
    md = folder / "planar.md"
    defs = "\n".join(f"- **{k}**: {v}" for k, v in METRICS.items())
    md.write_text(
        f"# {SUITE}: our methods beside the published table\n\n{text}\n"
        f"Metric definitions:\n\n{defs}\n\n"
        "Published rows: CORE-SNU/FCP-MPC's table (Trajectron++ predictions, their machine). "
        "Ours: this machine; see the Planar protocol page of the documentation for what "
        "differs.\n"
    )
    path = folder / "planar.csv"
    keys = [
        "dataset",
        "method",
        "definition",
        "predictor",
        "source",
        "n_seeds",
        "collision_rate",
        "collision_rate_min",
        "collision_rate_max",
        "n_reached",
        "n_scenarios",
        "infeasible_rate",
        "infeasible_rate_min",
        "infeasible_rate_max",
        "steps_to_goal",
        "steps_to_goal_min",
        "steps_to_goal_max",
        "timeout",
        "ctrl_time_ms",
    ]
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys, extrasaction="ignore")
        w.writeheader()
        for r in table:
            w.writerow(r)
    return {"markdown": md, "csv": path}


def report_command(folder: str, out: str | None) -> int:
    """``bench report FOLDER`` for a planar folder."""
    rows = read_planar_rows(folder)
    files = write_planar_report(rows, out or Path(folder) / "report")
    print(files["markdown"].read_text())
    print("wrote " + ", ".join(str(f) for f in files.values()))
    return 0
