"""fcp_mpc's matured pairs found for all plan steps in one lookup and scored from rows, with
the envelope's tables gathered at the anchors, equal the per-step form they replace (the
same fields, the same scores, bit for bit; the same calibration pairs and fits online), on
random crowds (hypothesis, derandomized), compiled."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from conformal_control.core.jit import compile_now
from conformal_control.families.cbf.controller import ControlState
from conformal_control.families.cbf.dynamics import Unicycle
from conformal_control.families.mpc import FCPMPC, FieldCalibration, Sampling, fieldcp
from conformal_control.predictors.base import Forecast, PredictionQuery, Predictor

compile_now()  # the compiled kernels are what must equal the forms they replace

DT = 0.4


class Drift(Predictor):
    """Every pedestrian keeps its current position plus a fixed drift per step."""

    def predict(self, query: PredictionQuery) -> Forecast:
        steps = np.arange(1, query.horizon + 1)[None, :, None]
        return Forecast(query.current[:, None, :] + 0.3 * steps * np.array([1.0, -0.5]))


def _observations(seed: int, n: int, agents: int, sub: int) -> list[PredictionQuery]:
    """Pedestrians on random walks sampled every DT / sub, each present at times, in a
    random order."""
    rng = np.random.default_rng(seed)
    cols = 8
    walk = 2.0 + np.cumsum(rng.normal(0.0, 0.3, (agents, n * sub + cols, 2)), axis=1)
    out = []
    for k in range(n):
        here = rng.permutation(np.flatnonzero(rng.random(agents) < 0.75))
        end = k * sub + cols
        out.append(
            PredictionQuery(
                ids=here.astype(np.int64),
                history=walk[here, end - cols : end].copy(),
                dt=DT / sub,
                horizon=sub,
                t=k * DT,
                frame=k,
                scene="t",
            )
        )
    return out


class PerStep(FCPMPC):
    """The matured pairs looked up one plan step at a time and scored through
    ``scales_needed`` on the whole grid's tables, the envelope read at every plan step:
    the forms the rows and the cut replace."""

    def plan_radius(self, lam: float, positions: np.ndarray) -> np.ndarray:
        r = self.required_clearance(lam)
        u = self.envelope_at(positions, lam)
        out: np.ndarray = np.where(r[None, :] > 0.0, u + r[None, :], -np.inf)
        return out

    def begin_interval(self, observation: PredictionQuery) -> None:
        m = self._steps_per_plan_step(observation)
        self._m = m
        super(FCPMPC, self).begin_interval(observation)
        h = int(self.sampling.horizon)
        ids = np.asarray(self._ids).astype(np.int64)
        cur = np.asarray(observation.current, dtype=float)[: ids.size]
        if self._first_seen.shape[0] == 0 and cur.shape[0]:
            self._first_seen = cur.copy()
        pred = (
            self.predicted_at(self.sampling.dt_plan * np.arange(1, h + 1))
            if ids.size
            else np.zeros((0, h, 2))
        )
        self._past.append({"ids": ids, "cur": cur, "pred": pred})
        matured = self._matured_per_step()
        self._scored = self._score_per_step(matured)
        if self.envelope is None:
            for k, pair in matured:
                self._pairs[k - 1].append(pair)
            self._since_fit += 1
            self._maybe_fit()

    def _matured_per_step(self) -> list[tuple[int, tuple[np.ndarray, np.ndarray]]]:
        past, now = self._past, self._past[-1]
        order = np.argsort(now["ids"], kind="stable")
        sorted_ids = now["ids"][order]
        out = []
        for h in range(1, int(self.sampling.horizon) + 1):
            back = h * self._m
            if back >= len(past):
                break
            made = past[-1 - back]
            if not (sorted_ids.size and made["ids"].size):
                continue
            k = np.minimum(np.searchsorted(sorted_ids, made["ids"]), sorted_ids.size - 1)
            i_made = np.flatnonzero(sorted_ids[k] == made["ids"])
            if i_made.size:
                i_now = order[k[i_made]]
                out.append((h, (made["pred"][i_made, h - 1], now["cur"][i_now])))
        return out

    def _score_per_step(
        self, matured: list[tuple[int, tuple[np.ndarray, np.ndarray]]]
    ) -> tuple[np.ndarray, np.ndarray]:
        env = self.envelope_
        if env is None or not matured:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        fields = [
            (h, p, o) for h, (p, o) in matured if h <= env.horizon and env.steps[h - 1] is not None
        ]
        if not fields:
            return np.zeros(0, dtype=np.int64), 1.0 - np.zeros(0)
        _, mean, lin, spread, slack, _ = env._stacked()  # the whole grid's tables
        steps = np.array([h for h, _, _ in fields], dtype=np.int64)
        bounds = np.concatenate([[0], np.cumsum([p.shape[0] for _, p, _ in fields])])
        got = fieldcp._scales_needed(
            steps,
            bounds.astype(np.int64),
            np.ascontiguousarray(np.concatenate([p for _, p, _ in fields])),
            np.ascontiguousarray(np.concatenate([o for _, _, o in fields])),
            np.ascontiguousarray(self._anchors, dtype=np.int64),
            np.ascontiguousarray(self._anchor_xy, dtype=np.float64),
            mean,
            lin,
            spread,
            slack,
        )
        self.n_fields_scored_ += len(fields)
        return steps, 1.0 - got


def _family(cls: type[FCPMPC], horizon: int, m: int, envelope: object = None) -> FCPMPC:
    fam = cls(
        Drift(),
        Unicycle(v_min=-0.8, v_max=0.8, omega_max=0.7, integrator="euler"),
        sampling=Sampling(n_samples=20, horizon=horizon, dt_plan=DT * m),
        d_c=0.5,
        substeps=1,
        envelope=envelope,
        calibration=FieldCalibration(grid_size=9, min_pairs=4, refit_every=3, n_mixtures=2),
    )
    fam.reset()
    return fam


def _run_both(fam: FCPMPC, ref: FCPMPC, obs: list[PredictionQuery]) -> None:
    x = np.zeros(5)
    goal = np.array([6.0, 1.0])
    for q in obs:
        fam.begin_interval(q)
        ref.begin_interval(q)
        for a, b in zip(fam._scored, ref._scored, strict=True):
            assert a.dtype == b.dtype and a.tobytes() == b.tobytes()
        assert fam.n_fields_scored_ == ref.n_fields_scored_
        assert fam.n_fits_ == ref.n_fits_
        for pa, pb in zip(fam._pairs, ref._pairs, strict=True):
            assert len(pa) == len(pb)
            for (p1, o1), (p2, o2) in zip(pa, pb, strict=True):
                assert p1.tobytes() == p2.tobytes() and o1.tobytes() == o2.tobytes()
        state = ControlState(x=x, t=q.t, step=0, goal=goal)
        c1, c2 = fam.decide(state, 0.1), ref.decide(state, 0.1)
        assert np.asarray(c1).tobytes() == np.asarray(c2).tobytes()
        r1, r2 = fam.interval_record(), ref.interval_record()
        assert r1.field_needed.tobytes() == r2.field_needed.tobytes()
        assert r1.field_step.tobytes() == r2.field_step.tobytes()
        x = x + np.array([0.2, 0.05, 0.0, 0.0, 0.0])
    assert fam.stats() == ref.stats()


@settings(max_examples=25, deadline=None, derandomize=True)
@given(
    seed=st.integers(0, 10_000),
    horizon=st.integers(2, 5),
    m=st.sampled_from([1, 2]),
    agents=st.integers(0, 6),
    sub=st.sampled_from([1, 2]),
)
def test_rows_equal_the_per_step_form_online_and_offline(
    seed: int, horizon: int, m: int, agents: int, sub: int
) -> None:
    """Online calibration (pairs, fits, scores on a learned envelope), then the envelope it
    learned given offline (every step with one scored from the rows, steps without one
    skipped): the same as the per-step form, interval by interval."""
    obs = _observations(seed, 24, agents, sub)
    fam, ref = _family(FCPMPC, horizon, m), _family(PerStep, horizon, m)
    _run_both(fam, ref, obs)
    env = fam.envelope_
    if env is None:
        return
    if len(env.steps) > 1:  # a step without an envelope: its fields are not scored
        env = fieldcp.FunctionalEnvelope(env.grid, (None, *env.steps[1:]), env.miscoverage)
    fam, ref = _family(FCPMPC, horizon, m, env), _family(PerStep, horizon, m, env)
    _run_both(fam, ref, _observations(seed + 1, 16, agents, sub))


def test_rows_scored_at_least_once_and_anchor_rows_cached():
    """The comparison above is not vacuous (fields were scored on a learned envelope), and
    the anchors' rows are gathered once per envelope and set of anchors."""
    obs = _observations(3, 30, 5, 1)
    fam, ref = _family(FCPMPC, 3, 1), _family(PerStep, 3, 1)
    _run_both(fam, ref, obs)
    assert fam.n_fits_ >= 1 and fam.n_fields_scored_ > 10
    env = fam.envelope_
    assert env is not None
    first = env.__dict__["_anchor_rows"][1]
    env.scales_of_rows(
        np.array([1]),
        np.array([0, 1]),
        np.zeros((1, 2)),
        np.ones((1, 2)),
        fam._anchors,
        fam._anchor_xy,
    )
    assert env.__dict__["_anchor_rows"][1] is first
    _, mean, _, _, _, _ = env._stacked()
    np.testing.assert_array_equal(first[1], mean[:, fam._anchors])


def test_plan_radius_reads_the_envelope_only_where_a_step_constrains():
    """Steps whose required clearance is 0 (relaxed) get -inf without a lookup: the same
    radii as reading every step, at several lambdas, on and off the grid."""
    obs = _observations(3, 30, 5, 1)
    fam, ref = _family(FCPMPC, 5, 1), _family(PerStep, 5, 1)
    _run_both(fam, ref, obs)
    r = fam.required_clearance(0.0)
    assert (r > 0).any() and (r == 0).any()  # both kinds of step
    pos = np.random.default_rng(4).uniform(-2.0, 8.0, (60, 5, 2))
    for lam in (0.0, 0.3, 0.3, -1.0, 0.3):
        assert fam.plan_radius(lam, pos).tobytes() == ref.plan_radius(lam, pos).tobytes()
    flat = _family(FCPMPC, 5, 1)  # not relaxed: every step constrains
    flat.constraint = type(flat.constraint)(relax=False)
    flat.reset()
    assert (flat.required_clearance(0.0) > 0).all()
    assert np.isfinite(flat.plan_radius(0.0, pos)).all()
