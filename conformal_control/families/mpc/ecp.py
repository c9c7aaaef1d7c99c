"""Egocentric conformal prediction in the sampling MPC (the ``ecp_mpc`` family).

ECP-MPC (Shin et al., "Egocentric Conformal Prediction for Safe and Efficient Navigation in
Dynamic Cluttered Environments", 2025) calibrates what matters to the robot rather than the
predictor's error: for a candidate position x at plan step h, the *egocentric score* of a
past time t' is how much the prediction made h steps before t' overestimated the distance
from x to the nearest pedestrian::

    s_h(x; t') = max(0, min_j |x - y^_j(t' | t' - h)| - min_j |x - y_j(t')|)

over the pedestrians seen at both times. The plan keeps x at least ``d_c + margin +
q_h(x)`` from every predicted position, with ``q_h(x)`` the conformal quantile at level
``1 - lambda`` of the scores of the last ``calibration_size`` times (each candidate position
gets its own region: the family's per-plan radius). lambda is that miscoverage level,
tracked by adaptive conformal inference (the ``aci`` rule, ``epsilon = alpha``); a larger
lambda = smaller regions = less conservative.

The loss of an interval (:class:`EgocentricMiscoverageLoss`) is the published update's
error: for every plan step h, the candidates planned h steps ago at the interval's start
are scored against what happened now, and a candidate counts as missed when its score
exceeds the quantile it was planned with; the loss is the fraction missed over candidates
and steps. It is the miscoverage of the regions as they were used (at the lambda of their
time), not re-evaluated at the interval's lambda.

Plan steps must be whole sampling periods (``dt_plan = m tau``), so that each plan step's
target is a sampling time whose observation is known. Where this differs from the published
ECP-MPC: one level for all plan steps (it runs one ACI per step), the conformal quantile
``ceil((B + 1)(1 - lambda))``-th smallest score (it interpolates ``numpy.quantile``), an
unbounded region capped at ``max_inflation`` (it uses ``0.5 dt h``, before calibration
``1.5 dt h``).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...core.base import Loss
from ...core.jit import kernel
from ...core.losses import check_lambda
from ...predictors.base import PredictionQuery, Predictor
from ..cbf.controller import ControlState
from ..cbf.roles import Dynamics, ReferenceController
from .controller import MPCIntervalRecord, Plan, PlanInputs, SamplingMPC
from .settings import Costs, Limits, Sampling

__all__ = ["ECPMPC", "ECPMPCIntervalRecord", "EgocentricMiscoverageLoss", "egocentric_quantiles"]

jit = kernel(cache=True, nogil=True)

#: Ranks (from either end) up to which :func:`_quantiles` keeps a candidate's quantile while
#: the scores come instead of storing them all (``calibration_size`` 15 at miscoverage 0.1:
#: the largest).
_SMALL_RANK = 2


@jit
def _kth(scores: np.ndarray, n: int, b_n: int, k: int, buf: np.ndarray) -> float:
    """The k-th smallest (1-based) of ``scores[:b_n, n]``: the order statistic kept in a small
    insertion buffer (the k smallest, or the ``b_n - k + 1`` largest when fewer), the same
    value as sorting them all and taking entry ``k - 1``."""
    top = b_n - k + 1
    if top <= k:  # the `top` largest, descending: the k-th smallest is the last of them
        cnt = 0
        for b in range(b_n):
            v = scores[b, n]
            if cnt < top:
                i = cnt
                cnt += 1
            elif v > buf[top - 1]:
                i = top - 1
            else:
                continue
            while i > 0 and buf[i - 1] < v:
                buf[i] = buf[i - 1]
                i -= 1
            buf[i] = v
        return buf[top - 1]  # type: ignore[no-any-return]
    cnt = 0  # the k smallest, ascending
    for b in range(b_n):
        v = scores[b, n]
        if cnt < k:
            i = cnt
            cnt += 1
        elif v < buf[k - 1]:
            i = k - 1
        else:
            continue
        while i > 0 and buf[i - 1] > v:
            buf[i] = buf[i - 1]
            i -= 1
        buf[i] = v
    return buf[k - 1]  # type: ignore[no-any-return]


@jit
def _nearest_candidates(
    pts: np.ndarray,
    m: int,
    lox: float,
    hix: float,
    loy: float,
    hiy: float,
    tol: float,
    keep: np.ndarray,
) -> int:
    """The points ``pts[:m]`` that can be the nearest of some candidate in the box
    ``[lox, hix] x [loy, hiy]``, their indices written into ``keep`` (ascending); returns
    how many. A point whose squared distance from the box exceeds, by ``tol``, the least
    squared distance from any point to the box's farthest corner is farther than that point
    from every candidate: never the minimum (the bound and its rounding margin: the MPC
    evaluation's cut, ``families/mpc/kernels.py``, ``_kept_agents``). With ``tol`` not
    finite, every point."""
    top = np.inf
    for j in range(m):
        x = pts[j, 0]
        y = pts[j, 1]
        fx = max(hix - x, x - lox)
        fy = max(hiy - y, y - loy)
        u = fx * fx + fy * fy
        if u < top:
            top = u
    k = 0
    for j in range(m):
        x = pts[j, 0]
        y = pts[j, 1]
        gx = max(0.0, lox - x, x - hix)
        gy = max(0.0, loy - y, y - hiy)
        if gx * gx + gy * gy > top + tol:
            continue
        keep[k] = j
        k += 1
    return k


@jit
def _quantiles(
    pos: np.ndarray,
    cal_pred: np.ndarray,
    cal_obs: np.ndarray,
    cal_n: np.ndarray,
    cal_b: np.ndarray,
    lam: float,
    cut: bool,
) -> np.ndarray:
    # For each (step, calibration time, pedestrian) the candidates are the inner loop: the
    # nearest distances kept per candidate by selects rather than branches, so the loop
    # compiles to vector instructions (the same numbers as one candidate at a time: the
    # same squared distances, their minimum, one square root each). ``cut``: each nearest
    # distance is taken over the pedestrians that can be the nearest of some candidate of
    # the step (a minimum selects: the same numbers, see _nearest_candidates).
    # The quantile, the k-th smallest of a candidate's B scores, is its (B - k + 1)-th
    # largest: when either rank is at most SMALL_RANK, it is kept while the scores come,
    # for all candidates together (a short insertion by max/min selects: the scores are
    # never NaN, so these order them exactly); else the scores are stored and each
    # candidate's k-th is selected (_kth).
    n_plans, horizon = pos.shape[0], pos.shape[1]
    out = np.empty((n_plans, horizon))
    scores = np.empty((max(cal_pred.shape[1], 1), n_plans))
    px = np.empty(n_plans)
    py = np.empty(n_plans)
    dp = np.empty(n_plans)
    do = np.empty(n_plans)
    buf = np.empty(max(cal_pred.shape[1], 1))
    ranks = np.empty((_SMALL_RANK, n_plans))
    kp = np.empty(cal_pred.shape[2], dtype=np.int64)
    ko = np.empty(cal_pred.shape[2], dtype=np.int64)
    for h in range(horizon):
        b_n = cal_b[h]
        if lam >= 1.0:
            out[:, h] = -np.inf
            continue
        k = math.ceil((b_n + 1) * (1.0 - lam))
        if lam <= 0.0 or b_n == 0 or k > b_n:
            out[:, h] = np.inf
            continue
        kk = max(k, 1)
        top = b_n - kk + 1
        # kept while the scores come: the `top` largest (descending) or the kk smallest
        # (ascending) in ranks[:r]; 0: stored and selected afterwards
        large = top <= _SMALL_RANK and top <= kk
        r = top if large else (kk if kk <= _SMALL_RANK else 0)
        for i in range(r):
            ranks[i, :] = -np.inf if large else np.inf
        lox, hix, loy, hiy = np.inf, -np.inf, np.inf, -np.inf
        for n in range(n_plans):
            px[n] = pos[n, h, 0]
            py[n] = pos[n, h, 1]
            lox, hix = min(lox, px[n]), max(hix, px[n])
            loy, hiy = min(loy, py[n]), max(hiy, py[n])
        big = max(abs(lox), abs(hix), abs(loy), abs(hiy))
        for b in range(b_n):
            m = cal_n[h, b]
            if m == 0:
                do[:] = 0.0  # every score 0: sqrt(0) - sqrt(0)
                dp[:] = 0.0
            else:
                scale = big
                for j in range(m):
                    scale = max(scale, abs(cal_pred[h, b, j, 0]), abs(cal_pred[h, b, j, 1]))
                    scale = max(scale, abs(cal_obs[h, b, j, 0]), abs(cal_obs[h, b, j, 1]))
                # the kernels' rounding margin (CUT_MARGIN (1 + S^2), twice); nothing cut
                # without ``cut`` or with a non-finite coordinate
                tol = 2e-9 * (1.0 + scale * scale) if cut and n_plans > 0 else np.inf
                mp = _nearest_candidates(cal_pred[h, b], m, lox, hix, loy, hiy, tol, kp)
                mo = _nearest_candidates(cal_obs[h, b], m, lox, hix, loy, hiy, tol, ko)
                dp[:] = np.inf
                do[:] = np.inf
                for i in range(mp):
                    qx = cal_pred[h, b, kp[i], 0]
                    qy = cal_pred[h, b, kp[i], 1]
                    for n in range(n_plans):
                        ax = px[n] - qx
                        ay = py[n] - qy
                        e = ax * ax + ay * ay
                        dp[n] = e if e < dp[n] else dp[n]
                for i in range(mo):
                    ox = cal_obs[h, b, ko[i], 0]
                    oy = cal_obs[h, b, ko[i], 1]
                    for n in range(n_plans):
                        ax = px[n] - ox
                        ay = py[n] - oy
                        e = ax * ax + ay * ay
                        do[n] = e if e < do[n] else do[n]
            if r == 0:
                for n in range(n_plans):
                    s = math.sqrt(dp[n]) - math.sqrt(do[n])
                    scores[b, n] = s if s > 0.0 else 0.0
            elif large and r == 1:
                r1 = ranks[0]
                for n in range(n_plans):
                    s = math.sqrt(dp[n]) - math.sqrt(do[n])
                    v = s if s > 0.0 else 0.0
                    r1[n] = v if v > r1[n] else r1[n]
            elif large:  # r == 2: insert v, the larger stays, the smaller moves on
                r1 = ranks[0]
                r2 = ranks[1]
                for n in range(n_plans):
                    s = math.sqrt(dp[n]) - math.sqrt(do[n])
                    v = s if s > 0.0 else 0.0
                    u = r1[n]
                    r1[n] = v if v > u else u
                    v = u if v > u else v
                    r2[n] = v if v > r2[n] else r2[n]
            elif r == 1:
                r1 = ranks[0]
                for n in range(n_plans):
                    s = math.sqrt(dp[n]) - math.sqrt(do[n])
                    v = s if s > 0.0 else 0.0
                    r1[n] = v if v < r1[n] else r1[n]
            else:
                r1 = ranks[0]
                r2 = ranks[1]
                for n in range(n_plans):
                    s = math.sqrt(dp[n]) - math.sqrt(do[n])
                    v = s if s > 0.0 else 0.0
                    u = r1[n]
                    r1[n] = v if v < u else u
                    v = u if v < u else v
                    r2[n] = v if v < r2[n] else r2[n]
        if r == 0:
            for n in range(n_plans):
                out[n, h] = _kth(scores, n, b_n, kk, buf)
        else:
            for n in range(n_plans):
                out[n, h] = ranks[r - 1, n]
    return out


def egocentric_quantiles(
    pos: np.ndarray,
    cal_pred: np.ndarray,
    cal_obs: np.ndarray,
    cal_n: np.ndarray,
    cal_b: np.ndarray,
    lam: float,
    *,
    cut: bool = True,
) -> np.ndarray:
    """Egocentric conformal quantile of every candidate position, shape (N, H) (m;
    ``inf``: unbounded region, ``-inf``: empty).

    Parameters
    ----------
    pos : ndarray of shape (N, H, 2)
        Candidate positions at plan steps 1..H.
    cal_pred, cal_obs : ndarrays of shape (H, B, M, 2)
        For plan step h and calibration time b, the predicted (made h steps earlier) and
        observed positions of the pedestrians seen at both times (the first
        ``cal_n[h, b]`` rows).
    cal_n : int ndarray of shape (H, B)
    cal_b : int ndarray of shape (H,)
        Calibration times available per step.
    lam : float
        Miscoverage level.
    cut : bool
        Take each nearest distance over the pedestrians that can be the nearest of some
        candidate of the step only (the same numbers, bit for bit; see
        :func:`_nearest_candidates`); False: over all of them (the reference).
    """
    out: np.ndarray = _quantiles(
        np.ascontiguousarray(pos, dtype=np.float64),
        np.ascontiguousarray(cal_pred, dtype=np.float64),
        np.ascontiguousarray(cal_obs, dtype=np.float64),
        np.ascontiguousarray(cal_n, dtype=np.int64),
        np.ascontiguousarray(cal_b, dtype=np.int64),
        float(lam),
        bool(cut),
    )
    return out


@jit
def _missed_kernel(
    xx: np.ndarray, xy: np.ndarray, pred: np.ndarray, obs: np.ndarray, q: np.ndarray
) -> np.ndarray:
    n = xx.shape[0]
    dp = np.full(n, np.inf)
    do = np.full(n, np.inf)
    for j in range(pred.shape[0]):  # the candidates inner: vector instructions
        qx = pred[j, 0]
        qy = pred[j, 1]
        ox = obs[j, 0]
        oy = obs[j, 1]
        for i in range(n):
            dx = xx[i] - qx
            dy = xy[i] - qy
            e = dx * dx + dy * dy
            dp[i] = e if e < dp[i] else dp[i]
            dx = xx[i] - ox
            dy = xy[i] - oy
            e = dx * dx + dy * dy
            do[i] = e if e < do[i] else do[i]
    out = np.empty(n, dtype=np.bool_)
    for i in range(n):
        s = math.sqrt(dp[i]) - math.sqrt(do[i])
        if not s > 0.0 and s == s:  # numpy.maximum(s, 0): NaN stays NaN
            s = 0.0
        out[i] = s > q[i]
    return out


def _missed(x: np.ndarray, pred: np.ndarray, obs: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Whether each candidate position's egocentric score against the pedestrians'
    predicted and observed positions exceeds its quantile: ``max(d(x, pred) - d(x, obs), 0)
    > q`` with ``d`` the distance to the nearest (the arithmetic of two
    :func:`~conformal_control.families.mpc.fieldcp.distance_field` calls, in one pass)."""
    c = np.ascontiguousarray
    out: np.ndarray = _missed_kernel(
        c(x[:, 0], dtype=np.float64),
        c(x[:, 1], dtype=np.float64),
        c(pred, dtype=np.float64).reshape(-1, 2),
        c(obs, dtype=np.float64).reshape(-1, 2),
        c(q, dtype=np.float64),
    )
    return out


@jit
def _missed_at(
    pos: np.ndarray, q: np.ndarray, h: int, pred: np.ndarray, obs: np.ndarray, n: int
) -> np.ndarray:
    """:func:`_missed` for the candidates ``pos[:, h]`` with the quantiles ``q[:, h]`` and
    the first ``n`` pedestrians of ``pred`` and ``obs``, without copies, each nearest
    distance taken over the pedestrians that can be the nearest of some candidate (the
    same numbers, bit for bit: a minimum selects; see :func:`_nearest_candidates`)."""
    n_pos = pos.shape[0]
    xx = np.empty(n_pos)  # the candidates' coordinates, contiguous
    xy = np.empty(n_pos)
    lox, hix, loy, hiy = np.inf, -np.inf, np.inf, -np.inf
    for i in range(n_pos):
        xx[i] = pos[i, h, 0]
        xy[i] = pos[i, h, 1]
        lox, hix = min(lox, xx[i]), max(hix, xx[i])
        loy, hiy = min(loy, xy[i]), max(hiy, xy[i])
    scale = max(abs(lox), abs(hix), abs(loy), abs(hiy))
    for j in range(n):
        scale = max(scale, abs(pred[j, 0]), abs(pred[j, 1]), abs(obs[j, 0]), abs(obs[j, 1]))
    tol = 2e-9 * (1.0 + scale * scale) if n_pos > 0 else np.inf
    kp = np.empty(max(n, 1), dtype=np.int64)
    ko = np.empty(max(n, 1), dtype=np.int64)
    mp = _nearest_candidates(pred, n, lox, hix, loy, hiy, tol, kp)
    mo = _nearest_candidates(obs, n, lox, hix, loy, hiy, tol, ko)
    dp = np.full(n_pos, np.inf)
    do = np.full(n_pos, np.inf)
    for t in range(mp):
        qx = pred[kp[t], 0]
        qy = pred[kp[t], 1]
        for i in range(n_pos):
            dx = xx[i] - qx
            dy = xy[i] - qy
            e = dx * dx + dy * dy
            dp[i] = e if e < dp[i] else dp[i]
    for t in range(mo):
        ox = obs[ko[t], 0]
        oy = obs[ko[t], 1]
        for i in range(n_pos):
            dx = xx[i] - ox
            dy = xy[i] - oy
            e = dx * dx + dy * dy
            do[i] = e if e < do[i] else do[i]
    out = np.empty(n_pos, dtype=np.bool_)
    for i in range(n_pos):
        s = math.sqrt(dp[i]) - math.sqrt(do[i])
        if not s > 0.0 and s == s:  # numpy.maximum(s, 0): NaN stays NaN
            s = 0.0
        out[i] = s > q[i, h]
    return out


@jit
def _roll_pairs(
    now_ids: np.ndarray,
    now_cur: np.ndarray,
    made_ids: np.ndarray,
    made_off: np.ndarray,
    made_pred: np.ndarray,
    cal_pred: np.ndarray,
    cal_obs: np.ndarray,
    cal_n: np.ndarray,
) -> bool:
    """The calibration arrays moved one sampling time back (``b`` to ``b + 1``) and, at
    ``b = 0`` of every step h, the pedestrians seen now and h plan steps ago: observed
    positions ``now_cur`` and that time's predictions ``made_pred[made_off[h]:made_off[h +
    1]]`` (ids ``made_ids``, same slices), in ascending id, as ``numpy.intersect1d`` of
    unique ids orders them. Returns False (nothing written) when ids repeat."""
    order = np.argsort(now_ids)
    for i in range(1, order.shape[0]):
        if now_ids[order[i]] == now_ids[order[i - 1]]:
            return False
    for h in range(cal_n.shape[0]):
        a0, a1 = made_off[h], made_off[h + 1]
        sub = np.argsort(made_ids[a0:a1])
        for i in range(1, sub.shape[0]):
            if made_ids[a0 + sub[i]] == made_ids[a0 + sub[i - 1]]:
                return False
    for h in range(cal_n.shape[0]):
        for b in range(cal_n.shape[1] - 1, 0, -1):
            k = cal_n[h, b - 1]
            for j in range(k):
                cal_pred[h, b, j, 0] = cal_pred[h, b - 1, j, 0]
                cal_pred[h, b, j, 1] = cal_pred[h, b - 1, j, 1]
                cal_obs[h, b, j, 0] = cal_obs[h, b - 1, j, 0]
                cal_obs[h, b, j, 1] = cal_obs[h, b - 1, j, 1]
            cal_n[h, b] = k
        a0, a1 = made_off[h], made_off[h + 1]
        sub = np.argsort(made_ids[a0:a1])
        i = 0
        j = 0
        k = 0
        while i < order.shape[0] and j < sub.shape[0]:
            u = now_ids[order[i]]
            v = made_ids[a0 + sub[j]]
            if u < v:
                i += 1
            elif v < u:
                j += 1
            else:
                cal_obs[h, 0, k, 0] = now_cur[order[i], 0]
                cal_obs[h, 0, k, 1] = now_cur[order[i], 1]
                cal_pred[h, 0, k, 0] = made_pred[a0 + sub[j], 0]
                cal_pred[h, 0, k, 1] = made_pred[a0 + sub[j], 1]
                k += 1
                i += 1
                j += 1
        cal_n[h, 0] = k
    return True


@dataclass
class ECPMPCIntervalRecord(MPCIntervalRecord):
    """The MPC record plus the egocentric misses scored at the interval's start.

    Attributes
    ----------
    ego_missed : ndarray of shape (P,)
        For every (candidate, plan step) scored, whether its score exceeded the quantile it
        was planned with.
    """

    ego_missed: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))


class ECPMPC(
    SamplingMPC,
    default_loss="ego_miscoverage",
    lambda_unit="level",
    # with the fixed-eta rule (ACI's update when epsilon = alpha): alpha 0.1, step 0.02
    default_rule_params={"epsilon": 0.1, "eta": 0.02},
):
    """Sampling MPC with egocentric conformal regions (ECP-MPC, Shin et al. 2025).

    See the module docstring. Run it with the ``aci`` rule (``epsilon = alpha``) and the
    ``ego_miscoverage`` loss.

    Parameters
    ----------
    predictor, dynamics, reference, sampling, d_c, margin, limits, costs
        As for :class:`~conformal_control.families.mpc.controller.SamplingMPC`.
    fallback, continuous, substeps, random_state
        As for :class:`~conformal_control.families.mpc.controller.SamplingMPC`.
    calibration_size : int
        Past times whose scores calibrate each plan step (>= 1).
    max_inflation : float
        Largest inflation of the safe distance (m, >= 0), for unbounded regions.
    edge : {"escape", "paper"}
        The edge rule of :class:`~conformal_control.families.mpc.controller.SamplingMPC`.
    **grouped
        As for :class:`~conformal_control.families.mpc.controller.SamplingMPC`
        (``<group>__<field>``,
        or a former flat keyword with a ``DeprecationWarning``).
    """

    @classmethod
    def lambda_ceiling(cls, margin: float) -> float:
        """``inf``: lambda is a level here, the safe distance is never below ``d_c +
        margin`` whatever it is.

        Parameters
        ----------
        margin : float
            The family's fixed extra safe distance (m).
        """
        return math.inf

    def __init__(
        self,
        predictor: Predictor,
        dynamics: Dynamics,
        reference: ReferenceController | None = None,
        sampling: Sampling | None = None,
        d_c: float = 1.0,
        margin: float = 0.0,
        limits: Limits | None = None,
        costs: Costs | None = None,
        fallback: str = "brake",
        continuous: bool = True,
        substeps: int = 4,
        random_state: int = 0,
        calibration_size: int = 15,
        max_inflation: float = 2.0,
        edge: str = "escape",
        **grouped: Any,
    ) -> None:
        self.calibration_size = calibration_size
        self.max_inflation = max_inflation
        super().__init__(
            predictor,
            dynamics,
            reference,
            sampling,
            d_c,
            margin,
            limits,
            costs,
            fallback,
            continuous,
            substeps,
            random_state,
            edge,
            **grouped,
        )

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        base = super()._unit_test_params()[0]
        # the partner environment samples every 0.4 s: plan steps of one sampling period
        sampling = base["sampling"].replace(dt_plan=0.4)
        return [{**base, "sampling": sampling, "calibration_size": 4, "max_inflation": 1.0}]

    def reset(self) -> None:
        super().reset()
        b = self.calibration_size
        if isinstance(b, bool) or int(b) != b or b < 1:
            raise ValueError(f"calibration_size must be a positive integer, got {b!r}")
        if not (math.isfinite(self.max_inflation) and self.max_inflation >= 0):
            raise ValueError(
                f"max_inflation must be a finite distance >= 0, got {self.max_inflation!r}"
            )
        self._m = 0  # sampling periods per plan step (set at the first interval)
        keep = int(self.sampling.horizon) * 64 + int(b) + 2
        # per sampling time: ids, observed positions, predictions at the plan steps,
        # the first plan's candidates (N, H, 2) and their quantiles (N, H)
        self._past: deque[dict[str, Any]] = deque(maxlen=keep)
        self._cal: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        # the calibration pairs, kept rolling: (H, B, width, 2) predicted and observed
        # positions, (H, B) counts (b = 0 the newest sampling time; see _calibration)
        h = int(self.sampling.horizon)
        self._cal_pred = np.zeros((h, int(b), 1, 2))
        self._cal_obs = np.zeros((h, int(b), 1, 2))
        self._cal_n = np.zeros((h, int(b)), dtype=np.int64)
        self._last_q: np.ndarray | None = None
        self._missed = np.zeros(0, dtype=bool)
        self.n_ego_scored_ = 0

    def stats(self) -> dict[str, float]:
        return {**super().stats(), "n_ego_scored": self.n_ego_scored_}

    # ------------------------------------------------------------------ sampling time
    def _steps_per_plan_step(self, observation: PredictionQuery) -> int:
        tau = float(observation.horizon) * float(observation.dt)
        m = self.sampling.dt_plan / tau
        if abs(m - round(m)) > 1e-6 or round(m) < 1:
            raise ValueError(
                f"ecp_mpc needs plan steps of whole sampling periods: dt_plan = "
                f"{self.sampling.dt_plan:g} s, sampling period {tau:g} s"
            )
        return round(m)

    def begin_interval(self, observation: PredictionQuery) -> None:
        m = self._steps_per_plan_step(observation)
        if self._m and m != self._m:
            raise ValueError("the sampling period changed during the episode")
        self._m = m
        super().begin_interval(observation)
        h = int(self.sampling.horizon)
        ids = np.asarray(observation.ids).astype(np.int64)
        cur = np.asarray(observation.current, dtype=float)
        pred = (
            self.predicted_at(self.sampling.dt_plan * np.arange(1, h + 1))
            if ids.size
            else np.zeros((0, h, 2))
        )
        t = float(observation.t)
        entry = {"ids": ids, "cur": cur, "pred": pred, "pos": None, "q": None, "t": t}
        self._past.append(entry)
        now = self._roll()
        self._missed = self._score_plans(now)
        self._cal = self._calibration()

    def _made(self, h: int) -> dict[str, Any] | None:
        """The sampling time h plan steps before the newest, if kept."""
        back = h * self._m
        return self._past[-1 - back] if back < len(self._past) else None

    def _roll(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Move the calibration pairs one sampling time back and add the newest time's
        (:func:`_roll_pairs`, compiled); returns each step's pairs of now, (observed,
        predicted). The pairs of two times are the pedestrians in both, in ascending id
        (as ``numpy.intersect1d`` gives them), each pair computed once."""
        h_n, b_max = int(self.sampling.horizon), int(self.calibration_size)
        now = self._past[-1]
        made = [self._made(h) for h in range(1, h_n + 1)]
        sizes = [0 if e is None else e["ids"].shape[0] for e in made]
        width = max(self._cal_pred.shape[2], min(now["ids"].shape[0], max(sizes, default=0)))
        if width > self._cal_pred.shape[2]:  # wider: the pairs kept, copied over
            grown = np.zeros((h_n, b_max, width, 2)), np.zeros((h_n, b_max, width, 2))
            grown[0][:, :, : self._cal_pred.shape[2]] = self._cal_pred
            grown[1][:, :, : self._cal_obs.shape[2]] = self._cal_obs
            self._cal_pred, self._cal_obs = grown
        off = np.zeros(h_n + 1, dtype=np.int64)
        np.cumsum(sizes, out=off[1:])
        ids_h, pred_h = [], []  # the steps' earlier times, one after the other
        for h, e in enumerate(made, 1):
            if e is not None and e["ids"].shape[0]:
                ids_h.append(e["ids"])
                pred_h.append(e["pred"][:, h - 1])
        ids = np.concatenate(ids_h) if ids_h else np.zeros(0, np.int64)
        pred = np.concatenate(pred_h) if pred_h else np.zeros((0, 2))
        done = _roll_pairs(
            now["ids"],
            np.ascontiguousarray(now["cur"], dtype=np.float64).reshape(-1, 2),
            ids,
            off,
            np.ascontiguousarray(pred, dtype=np.float64),
            self._cal_pred,
            self._cal_obs,
            self._cal_n,
        )
        if not done:
            raise ValueError(
                f"ecp_mpc needs distinct pedestrian ids at each sampling time; ids repeat "
                f"at t = {now['t']:g} s"
            )
        n = self._cal_n[:, 0].tolist()
        return [(self._cal_obs[h, 0, : n[h]], self._cal_pred[h, 0, : n[h]]) for h in range(h_n)]

    def _score_plans(self, now: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        """Misses of the candidates planned h plan steps ago, scored against now (``now``:
        each step's pairs, as :meth:`_roll` returns them)."""
        out = []
        for h in range(1, int(self.sampling.horizon) + 1):
            made = self._made(h)
            if made is None:
                break
            if made["pos"] is None:
                continue
            y, yhat = now[h - 1]
            if y.shape[0] == 0:
                continue
            out.append(_missed_at(made["pos"], made["q"], h - 1, yhat, y, y.shape[0]))
        missed = np.concatenate(out) if out else np.zeros(0, dtype=bool)
        self.n_ego_scored_ += int(missed.size)
        return missed

    def _calibration(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The calibration pairs of every plan step (see :func:`egocentric_quantiles`): the
        arrays kept rolling by :meth:`_roll` (pedestrians past ``cal_n`` and times past
        ``cal_b`` are not read), with each step's number of calibration times."""
        h_n, b_max = int(self.sampling.horizon), int(self.calibration_size)
        n_past = len(self._past)
        cal_b = np.array(
            [min(b_max, max(0, n_past - h * self._m)) for h in range(1, h_n + 1)], dtype=np.int64
        )
        return self._cal_pred, self._cal_obs, self._cal_n, cal_b

    # ------------------------------------------------------------------ the knob
    def plan_radius(self, lam: float, positions: np.ndarray) -> np.ndarray:
        """``d_c + margin + min(q_h(x), max_inflation)`` per candidate and step (m)."""
        assert self._cal is not None  # set by begin_interval
        q = egocentric_quantiles(positions, *self._cal, lam)
        self._last_q = q
        infl = np.clip(np.where(np.isneginf(q), 0.0, q), 0.0, float(self.max_inflation))
        out: np.ndarray = np.maximum(float(self.d_c) + float(self.margin) + infl, 0.0)
        return out

    def plan_begin(self, state: ControlState, lam: float) -> PlanInputs:
        self._last_q = None
        return super().plan_begin(state, lam)

    def plan_end(
        self, todo: PlanInputs, cost: np.ndarray, clear: np.ndarray, viol: np.ndarray
    ) -> Plan:
        out = super().plan_end(todo, cost, clear, viol)
        entry = self._past[-1] if self._past else None
        if entry is not None and entry["pos"] is None and self._last_q is not None:
            # the interval's first plan: its candidates and quantiles, scored later
            entry["pos"] = self._candidates
            entry["q"] = self._last_q
        return out

    def interval_record(self) -> ECPMPCIntervalRecord:
        base = super().interval_record()
        fields = {k: getattr(base, k) for k in base.__dataclass_fields__}
        return ECPMPCIntervalRecord(**fields, ego_missed=self._missed.copy())


class EgocentricMiscoverageLoss(Loss[ECPMPCIntervalRecord, Any]):
    """Egocentric miscoverage of ecp_mpc: the fraction of (candidate, plan step) pairs,
    scored at the interval's start, whose egocentric score exceeded the quantile they were
    planned with (see :mod:`conformal_control.families.mpc.ecp`). In [0, 1]; target: the ``aci``
    rule's alpha. Nothing scored: no loss. The truth argument is not used."""

    bounds = (0.0, 1.0)

    def __init__(self) -> None:
        pass

    @classmethod
    def _unit_test_inputs(cls) -> list[tuple[ECPMPCIntervalRecord, Any]]:
        """A quarter missed; none missed; nothing scored."""

        def record(missed: np.ndarray) -> ECPMPCIntervalRecord:
            return ECPMPCIntervalRecord(
                ids=np.arange(1),
                x_ego=np.zeros((1, 2)),
                v_ego=np.zeros((1, 2)),
                x_pred=np.zeros((1, 1, 2)),
                v_pred=np.zeros((1, 1, 2)),
                lam_applied=np.zeros(1),
                status=["optimal"],
                ego_missed=missed,
            )

        return [
            (record(np.array([True, False, False, False])), None),
            (record(np.zeros(5, dtype=bool)), None),
            (record(np.zeros(0, dtype=bool)), None),
        ]

    def __call__(self, record: ECPMPCIntervalRecord, truth: Any, lam: float) -> float | None:
        check_lambda(lam)
        missed = np.asarray(record.ego_missed, dtype=bool)
        return float(missed.mean()) if missed.size else None
