"""Contract checks for :class:`~conformal_control.predictors.base.Predictor` plugins."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..predictors.base import Forecast, PredictionQuery, Predictor
from ._core import (
    CheckList,
    ContractError,
    assert_unchanged,
    clone,
    close,
    expect,
    max_abs_diff,
    plugin_label,
    snapshot,
    with_seed,
)
from .common import (
    check_capabilities,
    check_docstring_parameters,
    check_get_params_round_trip,
    check_no_mutable_defaults,
    check_pickle_round_trip,
    check_repr,
    sample_behaviour,
)

__all__ = [
    "check_predictor",
    "check_predictor_batch_consistent",
    "check_predictor_deterministic",
    "check_predictor_empty_query",
    "check_predictor_finite_on_clean_input",
    "check_predictor_horizon",
    "check_predictor_nan_padded_history",
    "check_predictor_no_mutation",
    "check_predictor_nonfinite_current",
    "check_predictor_output_shape",
    "make_query",
]

DT = 0.4  # s (2.5 fps, the ETH/UCY protocol)


def make_query(
    n_agents: int = 4,
    history: int = 10,
    horizon: int = 6,
    dt: float = DT,
    seed: int = 0,
    ground_truth: bool = False,
) -> PredictionQuery:
    """A small, clean query: agents walking at 0.5-1.5 m/s with 2 cm position noise.

    Parameters
    ----------
    n_agents : int
        Agents in the query.
    history : int
        Observed steps per agent.
    horizon : int
        Steps to predict.
    dt : float
        Seconds between two steps.
    seed : int
        Seed of the starts, headings, speeds and noise.
    ground_truth : bool
        Attach the true (noise-free continued) future, for oracle-like predictors.
    """
    rng = np.random.default_rng(seed)
    start = rng.uniform(0.0, 20.0, size=(n_agents, 2))
    heading = rng.uniform(0.0, 2.0 * np.pi, size=n_agents)
    speed = rng.uniform(0.5, 1.5, size=n_agents)
    vel = speed[:, None] * np.column_stack([np.cos(heading), np.sin(heading)])
    steps = np.arange(history + horizon, dtype=float)
    path = start[:, None, :] + vel[:, None, :] * (steps[None, :, None] * dt)
    path[:, :history] += rng.normal(0.0, 0.02, size=(n_agents, history, 2))
    return PredictionQuery(
        ids=np.arange(n_agents, dtype=np.int64),
        history=path[:, :history].copy(),
        dt=dt,
        horizon=horizon,
        t=12.0,
        frame=300,
        scene="contract-test",
        ground_truth=path[:, history:].copy() if ground_truth else None,
    )


def _query(plugin: Predictor, **kw: Any) -> PredictionQuery:
    return make_query(ground_truth=plugin.capabilities.requires_ground_truth, **kw)


def _subset(q: PredictionQuery, rows: np.ndarray) -> PredictionQuery:
    return PredictionQuery(
        ids=q.ids[rows],
        history=q.history[rows].copy(),
        dt=q.dt,
        horizon=q.horizon,
        t=q.t,
        frame=q.frame,
        scene=q.scene,
        ground_truth=None if q.ground_truth is None else q.ground_truth[rows].copy(),
    )


def _predict(plugin: Predictor, query: PredictionQuery, what: str) -> Forecast:
    try:
        out = plugin.predict(query)
    except Exception as exc:
        raise ContractError(
            f"{plugin_label(plugin)}: expected predict() to handle {what}, got "
            f"{type(exc).__name__}: {exc}"
        ) from exc
    expect(
        isinstance(out, Forecast),
        plugin,
        f"expected predict() to return a Forecast, got {type(out).__name__}",
    )
    return out


def _check_shape(plugin: Predictor, fc: Forecast, query: PredictionQuery, what: str) -> None:
    pos = fc.positions
    n, h = query.n_agents, query.horizon
    expect(
        isinstance(pos, np.ndarray),
        plugin,
        f"expected Forecast.positions to be a numpy array ({what}), got {type(pos).__name__}",
    )
    expect(
        pos.ndim == 3 and pos.shape[0] == n and pos.shape[1] >= h and pos.shape[2] == 2,
        plugin,
        f"expected Forecast.positions of shape ({n}, {h}, 2) for {n} agents and horizon {h} "
        f"({what}), got {pos.shape}",
    )
    expect(
        np.issubdtype(pos.dtype, np.floating),
        plugin,
        f"expected floating-point positions ({what}), got dtype {pos.dtype}",
    )
    cov = fc.covariance
    if cov is not None:
        cov = np.asarray(cov)
        expect(
            cov.ndim == 4
            and cov.shape[0] == n
            and cov.shape[1] == pos.shape[1]
            and cov.shape[2:] == (2, 2),
            plugin,
            f"expected Forecast.covariance of shape ({n}, {pos.shape[1]}, 2, 2) ({what}), "
            f"got {cov.shape}",
        )
        ok = np.isfinite(cov).all(axis=(-1, -2))
        if ok.any():
            c = cov[ok]
            sym = np.allclose(c, np.swapaxes(c, -1, -2), atol=1e-9, rtol=1e-6)
            eig = np.linalg.eigvalsh((c + np.swapaxes(c, -1, -2)) / 2).min() if sym else -1.0
            expect(
                sym and eig >= -1e-9 * max(1.0, float(np.abs(c).max())),
                plugin,
                f"expected symmetric positive semi-definite covariances ({what}), got "
                f"{'an asymmetric matrix' if not sym else f'smallest eigenvalue {eig:g}'}",
            )
    expect(
        isinstance(fc.info, dict),
        plugin,
        f"expected Forecast.info to be a dict of counters, got {type(fc.info).__name__}",
    )


# ---------------------------------------------------------------------------- checks
def check_predictor_output_shape(predictor: Predictor) -> None:
    """positions (N, >= horizon, 2) floats; covariance (N, H, 2, 2) PSD if given; info dict."""
    p = clone(predictor)
    p.reset()
    q = _query(p)
    _check_shape(p, _predict(p, q, "a clean query"), q, "clean query")


def check_predictor_finite_on_clean_input(predictor: Predictor) -> None:
    """Fully observed histories give finite predictions that start near the current position."""
    p = clone(predictor)
    p.reset()
    q = _query(p)
    pos = np.asarray(_predict(p, q, "a clean query").positions)
    expect(
        np.isfinite(pos).all(),
        plugin=p,
        what=f"expected finite positions for fully observed agents, got "
        f"{int((~np.isfinite(pos)).sum())} non-finite values",
    )
    # one sample ahead, pedestrians (<= 1.5 m/s here) move less than a few metres
    jump = np.linalg.norm(pos[:, 0, :] - q.current, axis=-1).max()
    expect(
        jump < 5.0,
        p,
        f"expected the first predicted sample within 5 m of the current position (positions "
        f"are absolute, in metres), got a jump of {jump:.3g} m",
    )


def check_predictor_no_mutation(predictor: Predictor) -> None:
    """predict() leaves the query (history, ids, ground truth, ...) untouched."""
    p = clone(predictor)
    p.reset()
    q = _query(p)
    q.history[1, :3] = np.nan  # NaN-padded rows are where in-place fixes tend to happen
    before = snapshot(q)
    _predict(p, q, "a query with a NaN-padded history")
    assert_unchanged(before, q, p, "query", "predict()")


def check_predictor_deterministic(predictor: Predictor) -> None:
    """Two fresh copies (same ``random_state`` if any) predict the same thing."""
    q = _query(predictor)
    outs = []
    for _ in range(2):
        p = with_seed(predictor, 0)
        p.reset()
        outs.append(_predict(p, q, "a clean query").positions)
    expect(
        close(outs[0], outs[1], rtol=1e-6, atol=1e-9),
        predictor,
        "expected identical predictions from two fresh copies with the same seed, got a max "
        f"difference of {max_abs_diff(outs[0], outs[1]):.3g} m",
    )


def check_predictor_batch_consistent(predictor: Predictor) -> None:
    """Predicting agents together or one at a time gives the same rows (batched = per agent)."""
    p = clone(predictor)
    p.reset()
    q = _query(p)
    full = np.asarray(_predict(p, q, "a clean query").positions, dtype=float)
    h = q.horizon
    for row in (0, q.n_agents - 1):
        p1 = clone(predictor)
        p1.reset()
        one = np.asarray(
            _predict(p1, _subset(q, np.array([row])), "a one-agent query").positions, dtype=float
        )
        expect(
            close(one[0, :h], full[row, :h], rtol=1e-5, atol=1e-6),
            p,
            f"expected agent {row}'s prediction not to depend on the other agents in the batch; "
            f"alone vs batched differ by up to "
            f"{max_abs_diff(one[0, :h], full[row, :h]):.3g} m",
        )


def check_predictor_nan_padded_history(predictor: Predictor) -> None:
    """Short (NaN-padded) histories and gaps are valid input: no error, others unaffected.

    Rows for such agents may be finite or NaN (the controller then holds the agent and
    counts it), never infinite; fully observed agents must get the same prediction as
    without the short ones in the batch.
    """
    p = clone(predictor)
    p.reset()
    q = _query(p, n_agents=5)
    clean = np.asarray(_predict(p, _subset(q, np.array([0, 4])), "a clean query").positions)
    q.history[1, :-3] = np.nan  # observed for 3 samples
    q.history[2, :-1] = np.nan  # observed once
    q.history[3, 3:6] = np.nan  # gap in the middle
    p = clone(predictor)
    p.reset()
    fc = _predict(p, q, "NaN-padded histories (short tracks, gaps)")
    _check_shape(p, fc, q, "NaN-padded histories")
    pos = np.asarray(fc.positions, dtype=float)
    expect(
        not np.isinf(pos).any(),
        p,
        "expected finite or NaN positions for agents with short histories, got inf",
    )
    h = q.horizon
    expect(
        close(pos[[0, 4], :h], clean[:, :h], rtol=1e-5, atol=1e-6),
        p,
        "expected NaN in one agent's history not to change the other agents' predictions; "
        f"they moved by up to {max_abs_diff(pos[[0, 4], :h], clean[:, :h]):.3g} m",
    )


def check_predictor_nonfinite_current(predictor: Predictor) -> None:
    """A non-finite current position (invalid input) gives a clear ValueError, or a counted
    fallback: a forecast with a positive counter in ``info`` and the other agents unharmed."""
    p = clone(predictor)
    p.reset()
    q = _query(p)
    q.history[1, -1] = [np.inf, np.nan]
    try:
        fc = p.predict(q)
    except ValueError as exc:
        expect(str(exc).strip() != "", p, "expected a ValueError with a message, got an empty one")
        return
    except Exception as exc:
        raise ContractError(
            f"{plugin_label(p)}: expected a ValueError (or a counted fallback) for a non-finite "
            f"current position, got {type(exc).__name__}: {exc}"
        ) from exc
    expect(isinstance(fc, Forecast), p, f"expected a Forecast, got {type(fc).__name__}")
    _check_shape(p, fc, q, "a non-finite current position")
    counted = any(
        isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) and v > 0
        for v in fc.info.values()
    )
    expect(
        counted,
        p,
        "expected either a ValueError or a counted fallback (a positive counter in "
        f"Forecast.info) for a non-finite current position, got info={fc.info!r}",
    )
    pos = np.asarray(fc.positions, dtype=float)
    others = np.delete(pos, 1, axis=0)
    expect(
        np.isfinite(others).all(),
        p,
        "expected the other agents' predictions to stay finite when one agent's current "
        "position is non-finite",
    )


def check_predictor_empty_query(predictor: Predictor) -> None:
    """No sensed agent: positions of shape (0, horizon, 2) (the loop still calls predict)."""
    p = clone(predictor)
    p.reset()
    q = _subset(_query(p), np.array([], dtype=int))
    _check_shape(p, _predict(p, q, "a query with no agent"), q, "no agent")


def check_predictor_horizon(predictor: Predictor) -> None:
    """The output follows the requested horizon (1 sample, and a longer one)."""
    for horizon in (1, 12):
        p = clone(predictor)
        p.reset()
        q = _query(p, horizon=horizon)
        _check_shape(p, _predict(p, q, f"horizon={horizon}"), q, f"horizon={horizon}")


@sample_behaviour.register(Predictor)
def _behaviour(predictor: Predictor) -> list[tuple[np.ndarray, object]]:
    """Forecasts of two sample queries after ``reset()`` (for the pickling check)."""
    predictor.reset()
    out: list[tuple[np.ndarray, object]] = []
    for seed in (0, 1):
        fc = predictor.predict(_query(predictor, seed=seed))
        out.append((np.asarray(fc.positions), fc.covariance))
    return out


#: Every predictor check, in order.
check_predictor = CheckList(
    "predictor",
    [
        check_get_params_round_trip,
        check_repr,
        check_capabilities,
        check_predictor_output_shape,
        check_predictor_finite_on_clean_input,
        check_predictor_no_mutation,
        check_predictor_deterministic,
        check_predictor_batch_consistent,
        check_predictor_nan_padded_history,
        check_predictor_nonfinite_current,
        check_predictor_empty_query,
        check_predictor_horizon,
        check_pickle_round_trip,
        check_docstring_parameters,
        check_no_mutable_defaults,
    ],
)
