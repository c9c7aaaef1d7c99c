"""fcp_mpc: distance fields, the functional envelope against brute force, the family's
constraint, scoring and errors."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from conformal_control.core import registry
from conformal_control.families.cbf.controller import ControlState
from conformal_control.families.cbf.dynamics import Unicycle
from conformal_control.families.mpc import FCPMPC, FieldCalibration, FieldConstraint, Sampling
from conformal_control.families.mpc.fcp import FieldMiscoverageLoss
from conformal_control.families.mpc.fieldcp import (
    FieldGrid,
    FunctionalEnvelope,
    distance_field,
    fit_envelope,
    fit_envelope_step,
    residual_field,
    step_distances,
)
from conformal_control.predictors.base import Forecast, PredictionQuery, Predictor

DT = 0.4


def test_distance_field_equals_a_brute_force_evaluation():
    rng = np.random.default_rng(0)
    pts, at = rng.normal(0, 3, (5, 2)), rng.normal(0, 4, (40, 2))
    got = distance_field(pts, at)
    want = [min(math.hypot(*(a - p)) for p in pts) for a in at]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert np.isinf(distance_field(np.zeros((0, 2)), at)).all()
    np.testing.assert_allclose(
        residual_field(pts + 0.3, pts, at),
        distance_field(pts + 0.3, at) - np.array(want),
        atol=1e-12,
    )


def test_grid_layout_and_lookup():
    g = FieldGrid(center=(1.0, -2.0), side=4.0, size=5)
    pts = g.points()
    assert pts.shape == (25, 2)
    np.testing.assert_allclose(pts[0], [-1.0, -4.0])  # row 0 along y, column 0 along x
    np.testing.assert_allclose(pts[1], [0.0, -4.0])
    np.testing.assert_allclose(pts[5], [-1.0, -3.0])
    flat, inside = g.cells(np.array([[0.1, -3.9], [1.0, -2.0], [3.5, 0.0]]))
    assert flat[:2].tolist() == [1, 12] and inside.tolist() == [True, True, False]
    with pytest.raises(ValueError, match="side"):
        FieldGrid(center=(0.0, 0.0), side=0.0)


def toy_fields(n: int = 60, seed: int = 0) -> tuple[FieldGrid, np.ndarray]:
    """Residual fields of one pedestrian predicted with a random error, on a 9 x 9 grid."""
    rng = np.random.default_rng(seed)
    grid = FieldGrid(center=(0.0, 0.0), side=6.0, size=9)
    at = grid.points()
    rows = []
    for _ in range(n):
        y = rng.uniform(-2, 2, (2, 2))
        yhat = y + rng.normal(0, 0.4, (2, 2))
        rows.append(residual_field(yhat, y, at))
    return grid, np.stack(rows)


def test_envelope_is_the_support_function_of_the_ellipsoids():
    grid, fields = toy_fields()
    step = fit_envelope_step(fields, 0.1, n_components=3, n_mixtures=2, random_state=1)
    assert step is not None
    # brute force: the largest reconstruction over many points of each ellipsoid's surface
    rng = np.random.default_rng(2)
    u = rng.normal(size=(8000, step.basis.shape[0]))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    for scale in (1.0, 0.5, 2.0):
        best = np.full(grid.n_points, -np.inf)
        for k in range(step.weights.size):
            chol = np.linalg.cholesky(step.covariances[k])
            c = step.means[k] + scale * step.radii[k] * u @ chol.T  # (P, p) on the surface
            best = np.maximum(best, (c @ step.basis).max(axis=0))
        brute = step.mean + best + step.slack
        got = step.values(np.arange(grid.n_points), scale)
        assert (got >= brute - 1e-9).all()  # the support function bounds every sample
        np.testing.assert_allclose(got, brute, atol=2e-2 * max(1.0, float(np.ptp(got))))


def test_calibration_level_and_coverage_against_brute_force():
    grid, fields = toy_fields(n=80)
    alpha = 0.2
    step = fit_envelope_step(fields, alpha, n_components=3, n_mixtures=2, random_state=3)
    assert step is not None
    # the same split, coefficients and mixture, densities written out by hand
    order = np.random.default_rng(3).permutation(80)
    cal = order[: math.ceil(0.3 * 80)]
    coef = (fields - step.mean) @ step.basis.T
    p = step.basis.shape[0]
    jitter = 1e-8 * np.eye(p)
    dens = []
    for c in coef[cal]:
        best = -np.inf
        for w, mu, cov in zip(step.weights, step.means, step.covariances - jitter, strict=True):
            d = c - mu
            logn = -0.5 * (d @ np.linalg.solve(cov, d)) - 0.5 * (
                p * math.log(2 * math.pi) + np.linalg.slogdet(cov)[1]
            )
            best = max(best, math.log(w) + logn)
        dens.append(best)
    dens = np.sort(dens)
    assert math.isclose(step.level, math.exp(np.quantile(dens, alpha)), rel_tol=1e-6)
    # the union of ellipsoids holds at least 1 - alpha of the calibration coefficients, up
    # to the interpolated quantile's one point
    inside = []
    for c in coef[cal]:
        m = [
            (c - mu) @ np.linalg.solve(cov, c - mu) <= r**2 + 1e-9
            for mu, cov, r in zip(step.means, step.covariances, step.radii, strict=True)
        ]
        inside.append(any(m))
    assert np.mean(inside) >= 1 - alpha - 1 / len(cal)
    # every calibration field inside the union whose projection residual is within the
    # slack lies below the envelope at every grid point
    recon = step.mean + coef @ step.basis
    resid = np.maximum(fields - recon, 0.0).max(axis=1)
    env = step.values(np.arange(grid.n_points))
    for i, ok in zip(cal, inside, strict=True):
        if ok and resid[i] <= step.slack:
            assert (fields[i] <= env + 1e-9).all()


def test_compiled_lookup_equals_the_steps_values():
    grid, fields = toy_fields()
    step = fit_envelope_step(fields, 0.1, n_components=3, n_mixtures=2)
    env = FunctionalEnvelope(grid=grid, steps=(step, None, step), miscoverage=0.1)
    pos = np.random.default_rng(6).uniform(-4, 4, (30, 4, 2))  # some outside the grid
    got = env.at(pos, scale=0.7, outside=-5.0)
    flat, inside = grid.cells(pos)
    for n in range(30):
        for h in range(4):
            if h in (1, 3) or not inside[n, h]:
                assert got[n, h] == -5.0
            else:
                assert math.isclose(got[n, h], step.values(flat[n, h : h + 1], 0.7)[0])
    assert pickle.loads(pickle.dumps(env)).at(pos, 0.7, -5.0).tolist() == got.tolist()
    f = fields[0][grid.anchors(16)]
    assert env.scale_needed(3, grid.anchors(16), f) == step.scale_needed(grid.anchors(16), f)
    assert env.scale_needed(2, grid.anchors(16), f) == -math.inf
    # several realised fields in one compiled pass, as one by one
    rng = np.random.default_rng(7)
    anchors = grid.anchors(16)
    at = grid.points(anchors)
    fields_ = [(h, rng.normal(0, 2, (m, 2)), rng.normal(0, 2, (m, 2))) for h, m in ((1, 3), (3, 1))]
    got_many = env.scales_needed(fields_, anchors, at)
    for (h, p, o), g in zip(fields_, got_many, strict=True):
        r = distance_field(p, at) - distance_field(o, at)
        assert g == env.scale_needed(h, anchors, r)
    with pytest.raises(ValueError, match="needs an envelope"):
        env.scales_needed([(2, p, o)], anchors, at)


def test_scale_needed_is_the_exact_threshold():
    grid, fields = toy_fields()
    step = fit_envelope_step(fields, 0.1, n_components=3, n_mixtures=2)
    assert step is not None
    anchors = grid.anchors(16)
    for f in fields[:10] * 1.5:
        s = step.scale_needed(anchors, f[anchors])
        if math.isfinite(s):
            assert (step.values(anchors, s + 1e-9) >= f[anchors] - 1e-9).all()
            assert not (step.values(anchors, s - 1e-6) >= f[anchors]).all()


def test_envelope_needs_enough_fields_and_valid_settings():
    grid, fields = toy_fields(n=3)
    assert fit_envelope_step(fields) is None
    for bad, match in (
        ({"miscoverage": 0.0}, "miscoverage"),
        ({"miscoverage": 1.0}, "miscoverage"),
        ({"calibration_share": 1.5}, "calibration_share"),
        ({"n_components": 0}, "n_components"),
        ({"slack": "lower"}, "slack"),
    ):
        with pytest.raises(ValueError, match=match) as err:
            fit_envelope([[]], grid, **bad)
        assert "\n" not in str(err.value)


def test_step_distances_equal_a_brute_force_evaluation():
    rng = np.random.default_rng(4)
    pos, pred = rng.normal(0, 3, (6, 4, 2)), rng.normal(0, 3, (3, 4, 2))
    got = step_distances(pos, pred)
    for n in range(6):
        for h in range(4):
            want = min(math.hypot(*(pos[n, h] - pred[j, h])) for j in range(3))
            assert math.isclose(got[n, h], want, abs_tol=1e-12)


class Frozen(Predictor):
    """Every pedestrian stays where it is."""

    def predict(self, query: PredictionQuery) -> Forecast:
        return Forecast(np.repeat(query.current[:, None, :], query.horizon, axis=1))


def query(k: int, pos: np.ndarray) -> PredictionQuery:
    hist = np.repeat(pos[:, None, :], 8, axis=1)
    return PredictionQuery(ids=np.arange(len(pos)), history=hist, dt=DT, horizon=1, t=k * DT)


def family(**kw) -> FCPMPC:
    params = {
        "predictor": Frozen(),
        "dynamics": Unicycle(v_min=-0.8, v_max=0.8, omega_max=0.7, integrator="euler"),
        "sampling": Sampling(n_samples=50, horizon=4, dt_plan=DT),
        "d_c": 1.1,
        "substeps": 1,
        "calibration": FieldCalibration(grid_size=9, min_pairs=4, refit_every=4, n_mixtures=2),
    }
    params.update(kw)
    return FCPMPC(**params)


def test_hard_radius_is_envelope_plus_relaxed_clearance():
    fam = family()
    fam.reset()
    r = fam.required_clearance(0.0)
    want = np.maximum(1.1 - 0.5 * 0.8 * 0.7 * (np.arange(4) * DT) ** 2, 0.0)
    np.testing.assert_allclose(r, want)
    fam.begin_interval(query(0, np.array([[2.0, 0.0]])))
    pos = np.random.default_rng(0).normal(0, 2, (5, 4, 2))
    rad = fam.plan_radius(0.0, pos)
    np.testing.assert_allclose(rad, fam.envelope_at(pos, 0.0) + r)  # uncalibrated: outside
    assert (fam.envelope_at(pos, 0.0) == 1.0).all()
    no_relax = family(constraint=FieldConstraint(relax=False))
    no_relax.reset()
    np.testing.assert_allclose(no_relax.required_clearance(0.0), np.full(4, 1.1))


def test_online_calibration_fits_and_scores_realised_fields():
    fam = family()
    fam.reset()
    rng = np.random.default_rng(5)
    ped = np.array([[3.0, 1.0], [4.0, -1.0]])
    x = np.array([0.0, 0.0, 0.0, 0.0, 0.0])
    scored = []
    for k in range(20):
        fam.begin_interval(query(k, ped))
        fam.decide(ControlState(x=x, t=k * DT, step=0, goal=np.array([8.0, 0.0])), 0.0)
        scored.append(fam.interval_record().field_needed.size)
        ped = ped + rng.normal(0, 0.3, ped.shape)  # the frozen predictor is wrong
    assert fam.n_fits_ >= 1 and fam.envelope_ is not None
    assert sum(scored) > 0 and fam.stats()["n_fields_scored"] == sum(scored)
    assert fam._grid is not None and fam.envelope_.grid == fam._grid


def test_soft_mode_never_excludes_and_penalises_intrusion():
    state = ControlState(x=np.zeros(5), t=0.0, step=0, goal=np.array([8.0, 0.0]))
    ped = np.array([[1.5, 0.0]])  # on the way to the goal

    def plan(**kw):
        fam = family(**kw)
        fam.reset()
        fam.begin_interval(query(0, ped))
        return fam, fam.plan(state, 0.0)

    fam, soft = plan(constraint=FieldConstraint(mode="soft", w_safety=100.0))
    # every candidate is kept: the random ones and the stop seed (no warm start yet)
    assert soft.status == "optimal" and soft.n_safe == fam.sampling.n_samples + 1
    _, loose = plan(constraint=FieldConstraint(mode="soft", w_safety=0.0))  # same candidates
    pred = np.repeat(ped[:, None], 4, axis=1)
    near = step_distances(soft.positions[None], pred).min()
    assert near > step_distances(loose.positions[None], pred).min() + 0.1
    _, hard = plan()  # a hard constraint: the zone (U = 1 m + 1.1 m) holds the start
    assert hard.status == "brake"


def test_field_miscoverage_loss_is_monotone_in_lambda():
    loss = FieldMiscoverageLoss()
    rec, _ = FieldMiscoverageLoss._unit_test_inputs()[0]
    values = [loss(rec, None, lam) for lam in (-1.0, 0.0, 0.1, 0.7)]
    assert values == [0.0, 1 / 3, 2 / 3, 1.0]
    empty, _ = FieldMiscoverageLoss._unit_test_inputs()[2]
    assert loss(empty, None, 0.0) is None


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"calibration": FieldCalibration(miscoverage=0.0)}, "miscoverage"),
        ({"calibration": FieldCalibration(miscoverage=1.2)}, "miscoverage"),
        ({"constraint": FieldConstraint(mode="medium")}, "mode"),
        ({"calibration": FieldCalibration(min_pairs=2)}, "min_pairs"),
        ({"constraint": FieldConstraint(w_safety=-1.0)}, "w_safety"),
    ],
)
def test_bad_settings_give_one_line_errors(kw, match):
    with pytest.raises(ValueError, match=match) as err:
        family(**kw).reset()
    assert "\n" not in str(err.value)


def test_step_size_must_be_positive():
    with pytest.raises(ValueError, match="gamma") as err:
        registry.create("rule", "aci", alpha=0.1, gamma=0.0).reset()
    assert "\n" not in str(err.value)


def test_registered_with_its_loss():
    assert registry.get("family", "fcp_mpc") is FCPMPC
    assert registry.get("loss", "field_miscoverage") is FieldMiscoverageLoss
    assert FCPMPC.capabilities.default_loss == "field_miscoverage"


def test_distance_field_is_the_point_by_point_minimum_bit_for_bit():
    rng = np.random.default_rng(8)
    pts, at = np.round(rng.normal(0, 3, (7, 2)), 1), rng.normal(0, 4, (33, 2))
    want = []
    for ax, ay in at.tolist():
        best = math.inf
        for px, py in pts.tolist():
            dx, dy = ax - px, ay - py
            best = min(best, dx * dx + dy * dy)
        want.append(math.sqrt(best))
    assert distance_field(pts, at).tolist() == want


def test_a_repeated_scale_is_read_from_a_table_with_the_same_values():
    from conformal_control.families.mpc.fieldcp import _envelope_at

    grid, fields = toy_fields()
    step = fit_envelope_step(fields, 0.1, n_components=3, n_mixtures=2)
    env = FunctionalEnvelope(grid=grid, steps=(step, None, step), miscoverage=0.1)
    pos = np.random.default_rng(9).uniform(-4, 4, (50, 4, 2))  # some outside the grid

    def direct(scale: float) -> np.ndarray:
        return _envelope_at(pos, *env._stacked(), scale, -5.0)

    for scale in (0.7, 0.7, 0.7, 1.3, 0.7, 0.7):
        assert env.at(pos, scale, -5.0).tobytes() == direct(scale).tobytes()
    assert "_table" in env.__dict__  # the repeated scale was read from the table
    assert "_table" not in pickle.loads(pickle.dumps(env)).__dict__
