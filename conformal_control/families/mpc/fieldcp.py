"""Functional conformal prediction of distance fields: the calibration behind ``fcp_mpc``.

FCP-MPC ("From Prediction Uncertainty to Conformalized Distance Fields for Safe Motion
Planning", CORE-SNU/FCP-MPC, 2026) calibrates the error of a *distance field*, not of each
pedestrian's position. For a set of pedestrian positions Y the distance field on a grid of
points x is ``D_Y(x) = min_j |x - y_j|``; the **residual field** of a prediction made h steps
ahead is

    S_h(x) = D_{Y^}(x) - D_Y(x)

(predicted minus true distance to the nearest pedestrian, over the pedestrians predicted and
observed). From a set of residual fields of step h (one per past prediction time) it builds
an **upper envelope** U_h(x) that holds the whole field below it with probability about
``1 - alpha``, in the way of Lei, Rinaldo & Wasserman (2015)'s functional conformal sets:

1. project the fields on their first ``p`` principal components (basis ``phi``, mean ``m``);
2. split the coefficient vectors into a training part and a calibration part
   (``calibration_share``); fit a Gaussian mixture of ``K`` components (scikit-learn's
   :class:`~sklearn.mixture.GaussianMixture`) to the training part;
3. the density level ``tau`` is the ``alpha``-quantile of the calibration part's largest
   weighted component density ``max_k pi_k N(c; mu_k, Sigma_k)``: the set ``{c : max_k pi_k
   N(c) >= tau}`` is a union of ellipsoids ``(c - mu_k)^T Sigma_k^-1 (c - mu_k) <= r_k^2``
   holding about ``1 - alpha`` of the coefficient vectors;
4. the envelope is the support function of that union plus a slack for what the projection
   leaves out (the ``1 - alpha`` quantile of the calibration fields' largest pointwise
   residual of the projection)::

       U_h(x) = m(x) + max_k ( mu_k . phi(x) + s r_k sqrt(phi(x)^T Sigma_k phi(x)) ) + slack

   with ``s = 1`` as calibrated; the online adaptation of the published code moves ``s``
   (a multiplier of the radii), which is lambda's place in ``fcp_mpc``
   (:mod:`~conformal_control.families.mpc.fcp`).

Every step h has its own envelope. The grid (:class:`FieldGrid`) is a square of ``size x
size`` points; a position is looked up at its nearest grid point, and positions outside the
square get a fixed value (the family's ``outside``).

**Where this differs from the published code** (``cp/functional_cp.py``, read, not used):

* The slack. The published code takes the quantile of ``max_x max(Pi S(x) - S(x), 0)`` (how
  far the projection rises *above* the field); a bound of the field from above needs how
  far the field rises above its projection, ``max_x max(S(x) - Pi S(x), 0)``, which is this
  module's default (``slack="upper"``); ``slack="published"`` computes the published one.
* The principal components by scikit-learn's randomised SVD, the routine its randomised
  PCA (the published code's) calls, with the same seed and defaults; the fields are
  centred and projected in float64.
* The train/calibration split by a seeded permutation of numpy (the published code uses
  scikit-learn's ``train_test_split`` with seed 0: a different draw of the same size).
* A step with fewer than :data:`MIN_FIELDS` fields has no envelope (the published code
  copies the previous step's field into the empty steps of a sample).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...core.jit import kernel
from .kernels import agent_rows

__all__ = [
    "MIN_FIELDS",
    "SLACKS",
    "EnvelopeStep",
    "FieldGrid",
    "FunctionalEnvelope",
    "distance_field",
    "fit_envelope",
    "fit_envelope_step",
    "residual_field",
    "step_distances",
]

jit = kernel(cache=True, nogil=True)

#: Fewest residual fields a step's envelope is fitted from (two to train, one to calibrate
#: at the smallest share, and one more).
MIN_FIELDS = 4
#: How the projection slack is measured (see the module docstring).
SLACKS = ("upper", "published")


@dataclass(frozen=True)
class FieldGrid:
    """A square grid of ``size x size`` points in world coordinates (m).

    Point ``(i, j)`` (row i along y, column j along x) is at ``center + (-side/2 + j side /
    (size - 1), -side/2 + i side / (size - 1))``; its flat index is ``i size + j`` (the
    published grid's layout).

    Parameters
    ----------
    center : (float, float)
        Centre of the square (m).
    side : float
        Side length (m, > 0).
    size : int
        Points per side (>= 2).
    """

    center: tuple[float, float]
    side: float
    size: int = 128

    def __post_init__(self) -> None:
        if not (math.isfinite(self.side) and self.side > 0):
            raise ValueError(f"the grid's side must be a finite length > 0, got {self.side!r}")
        if isinstance(self.size, bool) or int(self.size) != self.size or self.size < 2:
            raise ValueError(f"the grid's size must be an integer >= 2, got {self.size!r}")
        c = tuple(float(v) for v in self.center)
        if len(c) != 2 or not all(math.isfinite(v) for v in c):
            raise ValueError(f"the grid's center must be a finite (x, y), got {self.center!r}")
        object.__setattr__(self, "center", c)

    @classmethod
    def around(cls, points: np.ndarray, margin: float = 2.0, size: int = 128) -> FieldGrid:
        """The square of the published runs: the bounding box of ``points`` grown by
        ``margin`` on every side, its longer side for both.

        Parameters
        ----------
        points : ndarray of shape (P, 2)
            Positions to cover (m); non-finite rows are ignored.
        margin : float
            Added on every side (m).
        size : int
            Points per side.
        """
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        p = p[np.isfinite(p).all(axis=1)]
        if p.shape[0] == 0:
            raise ValueError("a grid needs at least one finite point to cover")
        lo, hi = p.min(axis=0) - margin, p.max(axis=0) + margin
        side = float(max(hi - lo))
        mid = (lo + hi) / 2
        return cls(center=(float(mid[0]), float(mid[1])), side=side, size=size)

    @property
    def n_points(self) -> int:
        """Grid points in all."""
        return int(self.size) ** 2

    def axis(self) -> np.ndarray:
        """Offsets of the grid lines from the centre (m), shape (size,)."""
        out: np.ndarray = np.linspace(-self.side / 2, self.side / 2, int(self.size))
        return out

    def points(self, flat: np.ndarray | None = None) -> np.ndarray:
        """World positions of the grid points (all, or the flat indices ``flat``), shape
        (G, 2)."""
        a = self.axis()
        idx = np.arange(self.n_points) if flat is None else np.asarray(flat, dtype=np.int64)
        i, j = np.divmod(idx, int(self.size))
        out: np.ndarray = np.stack([self.center[0] + a[j], self.center[1] + a[i]], axis=-1)
        return out

    def cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat index of the nearest grid point of each position, and whether the position
        is inside the square (indices of outside positions are clipped, not meaningful).

        Parameters
        ----------
        xy : ndarray of shape (..., 2)
            Positions (m).
        """
        p = np.asarray(xy, dtype=float)
        n1 = int(self.size) - 1
        u = (p[..., 0] - self.center[0] + self.side / 2) / self.side * n1
        v = (p[..., 1] - self.center[1] + self.side / 2) / self.side * n1
        inside = (u >= 0.0) & (u <= n1) & (v >= 0.0) & (v <= n1)
        j = np.clip(np.rint(np.nan_to_num(u)), 0, n1).astype(np.int64)
        i = np.clip(np.rint(np.nan_to_num(v)), 0, n1).astype(np.int64)
        return i * int(self.size) + j, inside

    def anchors(self, n: int = 256) -> np.ndarray:
        """About ``n`` flat indices on a regular sub-grid (every ``round(sqrt(G / n))``-th
        row and column), where realised fields are scored online (the published
        adapter's anchors)."""
        size = int(self.size)
        stride = max(1, round(math.sqrt(size * size / max(1, n))))
        ii = np.arange(0, size, stride)
        out: np.ndarray = (ii[:, None] * size + ii[None, :]).reshape(-1).astype(np.int64)
        return out


@jit
def _distance_field(px: np.ndarray, py: np.ndarray, gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    # the field's points are the inner loop, the nearest squared distance kept by a select:
    # it compiles to vector instructions (the same numbers as one point at a time)
    out = np.full(gx.shape[0], np.inf)
    for j in range(px.shape[0]):
        qx = px[j]
        qy = py[j]
        for g in range(gx.shape[0]):
            dx = gx[g] - qx
            dy = gy[g] - qy
            e = dx * dx + dy * dy
            out[g] = e if e < out[g] else out[g]
    for g in range(gx.shape[0]):
        out[g] = math.sqrt(out[g])
    return out


def distance_field(points: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Distance from each of ``at`` to the nearest of ``points`` (``inf`` without points).

    Parameters
    ----------
    points : ndarray of shape (M, 2)
        Pedestrian positions (m, finite).
    at : ndarray of shape (G, 2)
        Where the field is evaluated (m).

    Returns
    -------
    ndarray of shape (G,)
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    g = np.asarray(at, dtype=np.float64).reshape(-1, 2)
    c = np.ascontiguousarray
    out: np.ndarray = _distance_field(c(p[:, 0]), c(p[:, 1]), c(g[:, 0]), c(g[:, 1]))
    return out


def residual_field(predicted: np.ndarray, true: np.ndarray, at: np.ndarray) -> np.ndarray:
    """The residual field ``D_predicted - D_true`` at ``at`` (m), shape (G,).

    Parameters
    ----------
    predicted, true : ndarrays of shape (M, 2)
        Predicted and observed positions of the same pedestrians (m).
    at : ndarray of shape (G, 2)
        Where the field is evaluated (m).
    """
    out: np.ndarray = distance_field(predicted, at) - distance_field(true, at)
    return out


@jit
def _step_distances(pos: np.ndarray, ex: np.ndarray, ey: np.ndarray) -> np.ndarray:
    n_plans, horizon = pos.shape[0], pos.shape[1]
    out = np.empty((n_plans, horizon))
    for n in range(n_plans):
        for h in range(horizon):
            best = np.inf
            for j in range(ex.shape[1]):
                dx = pos[n, h, 0] - ex[h, j]
                dy = pos[n, h, 1] - ey[h, j]
                e = dx * dx + dy * dy
                if e < best:
                    best = e
            out[n, h] = math.sqrt(best)
    return out


def step_distances(positions: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """Distance from each candidate's position at the end of each plan step to the nearest
    predicted pedestrian at that step (``inf`` without pedestrians), shape (N, H).

    Parameters
    ----------
    positions : ndarray of shape (N, H, 2)
        Candidate positions at plan steps 1..H (m).
    predicted : ndarray of shape (M, H, 2)
        Predicted pedestrian positions at plan steps 1..H (m).
    """
    ex, ey, _, _ = agent_rows(predicted, np.zeros((np.shape(predicted)[0], 2)))
    out: np.ndarray = _step_distances(np.ascontiguousarray(positions, dtype=np.float64), ex, ey)
    return out


@dataclass(frozen=True, eq=False)
class EnvelopeStep:
    """One plan step's calibrated envelope (see the module docstring).

    Attributes
    ----------
    mean : ndarray of shape (G,)
        The fields' mean m(x) (m).
    basis : ndarray of shape (p, G)
        Principal directions phi.
    means, covariances : ndarrays of shape (K, p) and (K, p, p)
        The mixture's components in coefficient space.
    weights : ndarray of shape (K,)
    radii : ndarray of shape (K,)
        Each ellipsoid's radius r_k at the calibrated level (Mahalanobis units).
    level : float
        The density level tau.
    slack : float
        The projection slack (m).
    n_fields : int
        Fields the step was fitted from.
    """

    mean: np.ndarray
    basis: np.ndarray
    means: np.ndarray
    covariances: np.ndarray
    weights: np.ndarray
    radii: np.ndarray
    level: float
    slack: float
    n_fields: int
    lin: np.ndarray = field(init=False, repr=False)
    spread: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        # per grid point: mu_k . phi(x) and r_k sqrt(phi(x)^T Sigma_k phi(x)), shape (K, G)
        lin = self.means @ self.basis
        quad = np.einsum("pg,kpq,qg->kg", self.basis, self.covariances, self.basis)
        spread = self.radii[:, None] * np.sqrt(np.clip(quad, 0.0, None))
        object.__setattr__(self, "lin", np.ascontiguousarray(lin))
        object.__setattr__(self, "spread", np.ascontiguousarray(spread))

    def values(self, flat: np.ndarray, scale: float = 1.0) -> np.ndarray:
        """U(x) at the grid points ``flat`` with the radii multiplied by ``scale``."""
        idx = np.asarray(flat, dtype=np.int64)
        top = (self.lin[:, idx] + scale * self.spread[:, idx]).max(axis=0)
        out: np.ndarray = self.mean[idx] + top + self.slack
        return out

    def scale_needed(self, flat: np.ndarray, residual: np.ndarray) -> float:
        """The smallest radius multiplier at which ``U >= residual`` at every grid point
        ``flat`` (``-inf``: any; ``inf``: none).

        Parameters
        ----------
        flat : int ndarray of shape (A,)
            Grid points.
        residual : ndarray of shape (A,)
            A realised residual field there (m).
        """
        idx = np.ascontiguousarray(flat, dtype=np.int64)
        res = np.ascontiguousarray(residual, dtype=np.float64)
        lin, spread = np.ascontiguousarray(self.lin.T), np.ascontiguousarray(self.spread.T)
        return float(_scale_needed(idx, res, self.mean, lin, spread, self.slack))


@jit
def _scale_needed(
    idx: np.ndarray,
    residual: np.ndarray,
    mean: np.ndarray,
    lin: np.ndarray,
    spread: np.ndarray,
    slack: float,
) -> float:
    """Per grid point the smallest multiplier s with max_k(lin + s spread) >= what the
    residual needs (a component with spread 0 holds at any s or at none); the largest.
    ``lin`` and ``spread`` of shape (G, K)."""
    worst = -np.inf
    for a in range(idx.shape[0]):
        g = idx[a]
        c = residual[a] - mean[g] - slack
        best = np.inf
        for k in range(lin.shape[1]):
            need = c - lin[g, k]
            b = spread[g, k]
            if b > 0.0:
                v = need / b
            else:
                v = -np.inf if need <= 0.0 else np.inf
            if v < best:
                best = v
        if best > worst:
            worst = best
    return worst


@jit
def _scales_needed(
    steps: np.ndarray,
    bounds: np.ndarray,
    pred: np.ndarray,
    obs: np.ndarray,
    idx: np.ndarray,
    at: np.ndarray,
    mean: np.ndarray,
    lin: np.ndarray,
    spread: np.ndarray,
    slack: np.ndarray,
) -> np.ndarray:
    """:meth:`FunctionalEnvelope.scales_needed` in one pass: field ``i`` is step
    ``steps[i]``'s pairs ``pred[bounds[i]:bounds[i + 1]]`` / ``obs[...]``."""
    # the anchors are the inner loop, their nearest distances kept by selects rather than
    # branches: it compiles to vector instructions (the same numbers as one anchor at a
    # time: the same squared distances, their minimum, one square root each)
    n_at = idx.shape[0]
    out = np.empty(steps.shape[0])
    res = np.empty(n_at)
    ax = np.ascontiguousarray(at[:, 0])
    ay = np.ascontiguousarray(at[:, 1])
    dp = np.empty(n_at)
    do = np.empty(n_at)
    for i in range(steps.shape[0]):
        h = steps[i] - 1
        dp[:] = np.inf
        do[:] = np.inf
        for j in range(bounds[i], bounds[i + 1]):
            qx = pred[j, 0]
            qy = pred[j, 1]
            ox = obs[j, 0]
            oy = obs[j, 1]
            for a in range(n_at):
                ex = ax[a] - qx
                ey = ay[a] - qy
                e = ex * ex + ey * ey
                dp[a] = e if e < dp[a] else dp[a]
                ex = ax[a] - ox
                ey = ay[a] - oy
                e = ex * ex + ey * ey
                do[a] = e if e < do[a] else do[a]
        for a in range(n_at):
            res[a] = math.sqrt(dp[a]) - math.sqrt(do[a])
        out[i] = _scale_needed(idx, res, mean[h], lin[h], spread[h], slack[h])
    return out


@jit
def _grid_point(x: float, y: float, cx: float, cy: float, side: float, size: int) -> int:
    """The flat index of the grid point nearest ``(x, y)`` as :meth:`FieldGrid.cells` finds
    it, or -1 outside the grid (the one lookup of :func:`_envelope_at` and
    :func:`_envelope_lookup`)."""
    n1 = size - 1
    u = (x - cx + side / 2) / side * n1
    v = (y - cy + side / 2) / side * n1
    if not ((u >= 0.0) & (u <= n1) & (v >= 0.0) & (v <= n1)):
        return -1
    return int(np.rint(v)) * size + int(np.rint(u))


@jit
def _envelope_at(
    pos: np.ndarray,
    geometry: np.ndarray,
    mean: np.ndarray,
    lin: np.ndarray,
    spread: np.ndarray,
    slack: np.ndarray,
    has: np.ndarray,
    scale: float,
    outside: float,
) -> np.ndarray:
    """:meth:`FunctionalEnvelope.at` for every (plan, step): the nearest grid point as
    :meth:`FieldGrid.cells` finds it, then the envelope's formula."""
    cx, cy, side, size = geometry[0], geometry[1], geometry[2], int(geometry[3])
    n_plans, horizon = pos.shape[0], pos.shape[1]
    out = np.empty((n_plans, horizon))
    for n in range(n_plans):
        for h in range(horizon):
            if h >= has.shape[0] or not has[h]:
                out[n, h] = outside
                continue
            g = _grid_point(pos[n, h, 0], pos[n, h, 1], cx, cy, side, size)
            out[n, h] = outside if g < 0 else _envelope_value(h, g, mean, lin, spread, slack, scale)
    return out


@jit
def _envelope_value(
    h: int,
    g: int,
    mean: np.ndarray,
    lin: np.ndarray,
    spread: np.ndarray,
    slack: np.ndarray,
    scale: float,
) -> float:
    """The envelope of step ``h`` at grid point ``g`` (one formula for the lookup of
    :func:`_envelope_at` and the table of :func:`_envelope_table`: the same bits)."""
    top = -np.inf
    for k in range(lin.shape[2]):
        val = lin[h, g, k] + scale * spread[h, g, k]
        if val > top:
            top = val
    return mean[h, g] + top + slack[h]  # type: ignore[no-any-return]


@jit
def _envelope_table(
    mean: np.ndarray,
    lin: np.ndarray,
    spread: np.ndarray,
    slack: np.ndarray,
    has: np.ndarray,
    scale: float,
) -> np.ndarray:
    """The envelope of every step with one at every grid point, shape (H, G) (0 for a
    step without one: never read)."""
    out = np.zeros((has.shape[0], mean.shape[1]))
    for h in range(has.shape[0]):
        if has[h]:
            for g in range(mean.shape[1]):
                out[h, g] = _envelope_value(h, g, mean, lin, spread, slack, scale)
    return out


@jit
def _envelope_lookup(
    pos: np.ndarray,
    geometry: np.ndarray,
    table: np.ndarray,
    has: np.ndarray,
    outside: float,
) -> np.ndarray:
    """:func:`_envelope_at` read from a table of :func:`_envelope_table` (the same grid
    point found the same way, the same value)."""
    cx, cy, side, size = geometry[0], geometry[1], geometry[2], int(geometry[3])
    n_plans, horizon = pos.shape[0], pos.shape[1]
    out = np.empty((n_plans, horizon))
    for n in range(n_plans):
        for h in range(horizon):
            if h >= has.shape[0] or not has[h]:
                out[n, h] = outside
                continue
            g = _grid_point(pos[n, h, 0], pos[n, h, 1], cx, cy, side, size)
            out[n, h] = outside if g < 0 else table[h, g]
    return out


@dataclass(frozen=True, eq=False)
class FunctionalEnvelope:
    """Calibrated envelopes of plan steps 1..H on one grid.

    Attributes
    ----------
    grid : FieldGrid
    steps : tuple of EnvelopeStep or None
        Step h's envelope at index h - 1 (None: not calibrated).
    miscoverage : float
        The alpha it was calibrated at.
    """

    grid: FieldGrid
    steps: tuple[EnvelopeStep | None, ...]
    miscoverage: float

    def _stacked(self) -> tuple[np.ndarray, ...]:
        """The steps' arrays stacked for the compiled lookup (built once)."""
        got = self.__dict__.get("_stack")
        if got is not None:
            return got  # type: ignore[no-any-return]  # set below, a tuple of arrays
        g = self.grid.n_points
        real = [s for s in self.steps if s is not None]
        k = max((s.weights.size for s in real), default=1)
        h = len(self.steps)
        # (H, G, K): a grid point's components side by side (the lookup reads them together)
        mean, slack = np.zeros((h, g)), np.zeros(h)
        lin, spread = np.full((h, g, k), -np.inf), np.zeros((h, g, k))
        has = np.zeros(h, dtype=np.bool_)
        for i, st in enumerate(self.steps):
            if st is None:
                continue
            kk = st.weights.size
            mean[i], slack[i], has[i] = st.mean, st.slack, True
            lin[i, :, :kk], spread[i, :, :kk] = st.lin.T, st.spread.T
        geometry = np.array([*self.grid.center, self.grid.side, float(self.grid.size)])
        stack = (geometry, mean, lin, spread, slack, has)
        object.__setattr__(self, "_stack", stack)
        return stack

    def __getstate__(self) -> dict[str, Any]:
        return {
            k: v
            for k, v in self.__dict__.items()
            if k not in ("_stack", "_table", "_last_scale", "_anchor_rows")
        }

    def scale_needed(self, step: int, flat: np.ndarray, residual: np.ndarray) -> float:
        """:meth:`EnvelopeStep.scale_needed` of plan step ``step`` (1..H; ``-inf`` for a
        step without an envelope: nothing to hold).

        Parameters
        ----------
        step : int
            Plan step, 1..H.
        flat : int ndarray of shape (A,)
            Grid points.
        residual : ndarray of shape (A,)
            A realised residual field there (m).
        """
        _, mean, lin, spread, slack, has = self._stacked()
        h = int(step) - 1
        if not 0 <= h < has.size or not has[h]:
            return -math.inf
        idx = np.ascontiguousarray(flat, dtype=np.int64)
        res = np.ascontiguousarray(residual, dtype=np.float64)
        return float(_scale_needed(idx, res, mean[h], lin[h], spread[h], float(slack[h])))

    def scales_needed(
        self,
        fields: Sequence[tuple[int, np.ndarray, np.ndarray]],
        flat: np.ndarray,
        at: np.ndarray,
    ) -> np.ndarray:
        """:meth:`scale_needed` of several realised fields at once (one compiled call): each
        field given by its plan step (1..H, with an envelope) and its ``(predicted,
        observed)`` positions, evaluated at the grid points ``flat`` (positions ``at``).

        Parameters
        ----------
        fields : sequence of (int, ndarray (M, 2), ndarray (M, 2))
            Plan step, predicted and observed positions of the same pedestrians (m).
        flat : int ndarray of shape (A,)
            Grid points.
        at : ndarray of shape (A, 2)
            Their positions (m).
        """
        if not fields:
            return np.zeros(0)
        steps = np.array([h for h, _, _ in fields], dtype=np.int64)
        sizes = [np.asarray(p).reshape(-1, 2).shape[0] for _, p, _ in fields]
        bounds = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        pred = np.concatenate([np.asarray(p, float).reshape(-1, 2) for _, p, _ in fields])
        obs = np.concatenate([np.asarray(o, float).reshape(-1, 2) for _, _, o in fields])
        return self.scales_of_rows(steps, bounds, pred, obs, flat, at)

    def scales_of_rows(
        self,
        steps: np.ndarray,
        bounds: np.ndarray,
        pred: np.ndarray,
        obs: np.ndarray,
        flat: np.ndarray,
        at: np.ndarray,
    ) -> np.ndarray:
        """:meth:`scales_needed` of fields given as rows: field ``i`` is plan step
        ``steps[i]`` with the pairs ``pred[bounds[i]:bounds[i + 1]]`` /
        ``obs[bounds[i]:bounds[i + 1]]``.

        Parameters
        ----------
        steps : int ndarray of shape (F,)
            Each field's plan step (1..H, with an envelope).
        bounds : int ndarray of shape (F + 1,)
            Where each field's rows start and end.
        pred, obs : ndarray of shape (P, 2)
            Predicted and observed positions of the same pedestrians (m).
        flat : int ndarray of shape (A,)
            Grid points.
        at : ndarray of shape (A, 2)
            Their positions (m).
        """
        _, _, _, _, slack, has = self._stacked()
        steps = np.asarray(steps, dtype=np.int64)
        if not steps.size:
            return np.zeros(0)
        if ((steps < 1) | (steps > has.size)).any() or not has[steps - 1].all():
            raise ValueError("every field's plan step needs an envelope")
        idx, mean, lin, spread = self._at_anchors(flat)
        c = np.ascontiguousarray
        out: np.ndarray = _scales_needed(
            steps,
            c(bounds, dtype=np.int64),
            c(pred, dtype=np.float64),
            c(obs, dtype=np.float64),
            idx,
            c(at, dtype=np.float64),
            mean,
            lin,
            spread,
            slack,
        )
        return out

    def _at_anchors(self, flat: np.ndarray) -> tuple[np.ndarray, ...]:
        """``(0..A-1, mean, lin, spread)`` of the grid points ``flat`` only (gathered once per
        set of points, the last one kept): the compiled scoring reads the same values from
        contiguous rows instead of 12 x A scattered ones of the whole grid's 11 MB tables
        (cache misses made it ~6x slower in the planar loop than alone, measured)."""
        flat = np.ascontiguousarray(flat, dtype=np.int64)
        key = flat.tobytes()
        got = self.__dict__.get("_anchor_rows")
        if got is not None and got[0] == key:
            return got[1]  # type: ignore[no-any-return]  # set below, a tuple of arrays
        _, mean, lin, spread, _, _ = self._stacked()
        c = np.ascontiguousarray
        gathered = (
            np.arange(flat.size, dtype=np.int64),
            c(mean[:, flat]),
            c(lin[:, flat, :]),
            c(spread[:, flat, :]),
        )
        object.__setattr__(self, "_anchor_rows", (key, gathered))
        return gathered

    @property
    def horizon(self) -> int:
        """Plan steps the envelope covers."""
        return len(self.steps)

    def at(self, positions: np.ndarray, scale: float = 1.0, outside: float = 1.0) -> np.ndarray:
        """U_h at each position of step h, shape (N, H): ``outside`` where a position is
        outside the grid or its step has no envelope (or is beyond the envelope's horizon).

        Parameters
        ----------
        positions : ndarray of shape (N, H, 2)
            Positions at plan steps 1..H (m).
        scale : float
            Multiplier of the radii (1: as calibrated).
        outside : float
            The value outside the grid and for uncalibrated steps (m).
        """
        pos = np.ascontiguousarray(positions, dtype=np.float64)
        geometry, mean, lin, spread, slack, has = self._stacked()
        scale = float(scale)
        # A scale asked for twice in a row (an envelope not adapted online: every plan
        # of the episode) is read from a table of the whole grid at that scale, built
        # once: one read per position instead of one per mixture component, from a
        # table 14 times smaller (the same values, _envelope_value)
        table = self.__dict__.get("_table")
        if table is None or table[0] != scale:
            if self.__dict__.get("_last_scale") != scale:
                object.__setattr__(self, "_last_scale", scale)
                out: np.ndarray = _envelope_at(
                    pos, geometry, mean, lin, spread, slack, has, scale, float(outside)
                )
                return out
            table = (scale, _envelope_table(mean, lin, spread, slack, has, scale))
            object.__setattr__(self, "_table", table)
        found: np.ndarray = _envelope_lookup(pos, geometry, table[1], has, float(outside))
        return found


def _gaussian_mixture(train: np.ndarray, k: int, seed: int) -> Any:
    """scikit-learn's Gaussian mixture (full covariances) on ``train``, with the published
    code's fallback when a fit fails: fewer components, more regularisation."""
    try:
        from sklearn.mixture import GaussianMixture
    except ImportError as exc:  # pragma: no cover - scikit-learn is a dependency of the extra
        raise ImportError(
            "fcp_mpc fits its envelopes with scikit-learn: pip install 'conformal-control[fcp]'"
        ) from exc
    k = int(min(k, train.shape[0]))
    try:
        return GaussianMixture(n_components=k, covariance_type="full", random_state=seed).fit(train)
    except (ValueError, np.linalg.LinAlgError) as err:
        last: Exception = err
    distinct = int(np.unique(train, axis=0).shape[0])
    for kk in range(max(1, min(k, distinct)), 0, -1):
        for reg in (1e-6, 1e-5, 1e-4, 1e-3):
            try:
                return GaussianMixture(
                    n_components=kk, covariance_type="full", random_state=seed, reg_covar=reg
                ).fit(train)
            except (ValueError, np.linalg.LinAlgError) as err:
                last = err
    raise ValueError(f"no Gaussian mixture could be fitted to {train.shape[0]} fields: {last}")


def _weighted_log_density(x: np.ndarray, gmm: Any) -> np.ndarray:
    """``log pi_k + log N(x; mu_k, Sigma_k)``, shape (n, K)."""
    from scipy.stats import multivariate_normal

    cols = [
        math.log(float(w)) + multivariate_normal(mean=mu, cov=cov, allow_singular=True).logpdf(x)
        for w, mu, cov in zip(gmm.weights_, gmm.means_, gmm.covariances_, strict=True)
    ]
    out: np.ndarray = np.stack([np.atleast_1d(c) for c in cols], axis=1)
    return out


def fit_envelope_step(
    fields: np.ndarray,
    miscoverage: float = 0.1,
    n_components: int = 5,
    n_mixtures: int = 7,
    calibration_share: float = 0.3,
    random_state: int = 0,
    slack: str = "upper",
    jitter: float = 1e-8,
) -> EnvelopeStep | None:
    """One step's envelope from its residual fields (None with fewer than
    :data:`MIN_FIELDS` fields).

    Parameters
    ----------
    fields : ndarray of shape (S, G)
        Residual fields (m), one per past prediction time.
    miscoverage : float
        alpha in (0, 1).
    n_components : int
        Principal components p (at most S and G).
    n_mixtures : int
        Mixture components K (at most the training fields).
    calibration_share : float
        Share of the fields held out to calibrate, in (0, 1).
    random_state : int
        Seed of the split and the mixture.
    slack : {"upper", "published"}
        How the projection slack is measured.
    jitter : float
        Added to the covariances' diagonal (the published code's 1e-8).
    """
    if np.shape(fields)[0] < MIN_FIELDS:
        return None
    from threadpoolctl import threadpool_limits  # a dependency of scikit-learn

    # small problems (K <= 7 components in p <= 5 dimensions): one BLAS thread, else the
    # threads' start-up and a shared machine's contention cost more than the arithmetic
    with threadpool_limits(limits=1):
        return _fit_step(
            np.asarray(fields, dtype=np.float64),
            miscoverage,
            n_components,
            n_mixtures,
            calibration_share,
            random_state,
            slack,
            jitter,
        )


def _fit_step(
    y: np.ndarray,
    miscoverage: float,
    n_components: int,
    n_mixtures: int,
    calibration_share: float,
    random_state: int,
    slack: str,
    jitter: float,
) -> EnvelopeStep:
    s, g = y.shape
    p = int(min(n_components, s, g))
    mean = y.mean(axis=0)
    centred = y - mean
    from sklearn.utils.extmath import randomized_svd

    _, _, vt = randomized_svd(centred, p, n_oversamples=10, random_state=random_state)
    basis = np.asarray(vt[:p], dtype=np.float64)
    coef = centred @ basis.T
    recon = mean + coef @ basis
    diff = (y - recon) if slack == "upper" else (recon - y)
    err = np.maximum(diff, 0.0).max(axis=1)
    rng = np.random.default_rng(random_state)
    order = rng.permutation(s)
    n_cal = max(1, math.ceil(calibration_share * s))
    n_cal = min(n_cal, s - 2)
    cal, train = order[:n_cal], order[n_cal:]
    slack_value = float(np.quantile(err[cal], 1.0 - miscoverage))
    gmm = _gaussian_mixture(coef[train], n_mixtures, random_state)
    logd = _weighted_log_density(coef[cal], gmm).max(axis=1)
    level = float(np.exp(np.quantile(logd, miscoverage)))
    covs = np.asarray(gmm.covariances_, dtype=float) + jitter * np.eye(p)
    weights = np.asarray(gmm.weights_, dtype=float)
    radii = np.zeros(weights.size)
    for k in range(weights.size):
        _, logdet = np.linalg.slogdet(covs[k])
        log_norm = 0.5 * (p * math.log(2 * math.pi) + logdet)
        val = math.log(max(level / max(weights[k], 1e-12), 1e-300)) + log_norm
        radii[k] = math.sqrt(max(0.0, -2.0 * val))
    return EnvelopeStep(
        mean=mean,
        basis=np.ascontiguousarray(basis),
        means=np.asarray(gmm.means_, dtype=float),
        covariances=covs,
        weights=weights,
        radii=radii,
        level=level,
        slack=slack_value,
        n_fields=s,
    )


def fit_envelope(
    pairs: Sequence[Sequence[tuple[np.ndarray, np.ndarray]]],
    grid: FieldGrid,
    miscoverage: float = 0.1,
    n_components: int = 5,
    n_mixtures: int = 7,
    calibration_share: float = 0.3,
    random_state: int = 0,
    slack: str = "upper",
) -> FunctionalEnvelope:
    """Envelopes of plan steps 1..H from prediction/observation pairs.

    Parameters
    ----------
    pairs : sequence of H sequences of (predicted, true)
        For plan step h (index h - 1), one ``(predicted (M, 2), true (M, 2))`` pair per
        past prediction time: the positions predicted h steps ahead and the positions then
        observed, of the same pedestrians (m). Pairs without a pedestrian are skipped.
    grid : FieldGrid
        Where the fields are evaluated.
    miscoverage, n_components, n_mixtures, calibration_share, random_state, slack
        As for :func:`fit_envelope_step`.

    Returns
    -------
    FunctionalEnvelope

    Raises
    ------
    ValueError
        For a miscoverage or calibration share outside (0, 1), a slack other than
        :data:`SLACKS`, or fewer than one principal or mixture component.
    """
    check_calibration(miscoverage, n_components, n_mixtures, calibration_share, slack)
    at = grid.points()
    steps: list[EnvelopeStep | None] = []
    for step_pairs in pairs:
        rows = [
            residual_field(np.asarray(p, float), np.asarray(t, float), at).astype(np.float32)
            for p, t in step_pairs
            if np.asarray(p).size
        ]
        fields = np.stack(rows) if rows else np.zeros((0, at.shape[0]), dtype=np.float32)
        steps.append(
            fit_envelope_step(
                fields,
                miscoverage,
                n_components,
                n_mixtures,
                calibration_share,
                random_state,
                slack,
            )
        )
    return FunctionalEnvelope(grid=grid, steps=tuple(steps), miscoverage=float(miscoverage))


def check_calibration(
    miscoverage: Any, n_components: Any, n_mixtures: Any, calibration_share: Any, slack: Any
) -> None:
    """One-line ``ValueError`` for a calibration setting out of range.

    Parameters
    ----------
    miscoverage : float
        Must be in (0, 1).
    n_components, n_mixtures : int
        Must be positive integers.
    calibration_share : float
        Must be in (0, 1).
    slack : str
        One of :data:`SLACKS`.
    """
    for name, v in (("miscoverage", miscoverage), ("calibration_share", calibration_share)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 < float(v) < 1.0:
            raise ValueError(f"{name} must be a number in (0, 1), got {v!r}")
    for name, v in (("n_components", n_components), ("n_mixtures", n_mixtures)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"{name} must be a positive integer, got {v!r}")
    if slack not in SLACKS:
        raise ValueError(f"slack must be one of {', '.join(SLACKS)}, got {slack!r}")
