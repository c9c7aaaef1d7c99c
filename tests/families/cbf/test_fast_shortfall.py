"""The collision and shortfall losses read the interval's smallest distance with a compiled
kernel (``safety_losses.smallest_distance``): the number ``numpy.nanmin`` takes of
:func:`~conformal_control.families.cbf.safety_losses.min_distances`, bit for bit, and None
exactly when no distance is finite."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conformal_control.core.jit import compile_now
from conformal_control.families.cbf import safety_losses as sl
from conformal_control.families.cbf.loss import CBFTruth
from conformal_control.families.cbf.records import CBFIntervalRecord

compile_now()


def _record(x: np.ndarray, n: int, scored: np.ndarray | None = None) -> CBFIntervalRecord:
    s = x.shape[0]
    return CBFIntervalRecord(
        ids=np.arange(n),
        x_ego=x,
        v_ego=np.zeros_like(x),
        x_pred=np.zeros((s, n, 2)),
        v_pred=np.zeros((s, n, 2)),
        lam_applied=np.zeros(s),
        scored=scored,
    )


def _before(record: CBFIntervalRecord, truth: CBFTruth) -> float | None:
    """The losses' reading before the kernel."""
    d = sl.min_distances(record, truth)
    if d.size == 0 or not np.isfinite(d).any():
        return None
    return float(np.nanmin(d))


def _bits(x: float | None) -> bytes | None:
    return None if x is None else np.float64(x).tobytes()


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@settings(max_examples=120, deadline=None, derandomize=True)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(0, 6),
    f=st.integers(1, 8),
    substeps=st.integers(1, 5),
    dt=st.sampled_from([0.1, 1 / 30, 0.4, 1 / 2.5]),
    scale=st.sampled_from([1.0, 30.0, 1e4]),
    unknown=st.sampled_from([0.0, 0.2, 1.0]),
    infinite=st.booleans(),
    data=st.data(),
)
def test_the_compiled_smallest_distance_equals_nanmin_of_min_distances(
    seed: int,
    n: int,
    f: int,
    substeps: int,
    dt: float,
    scale: float,
    unknown: float,
    infinite: bool,
    data,
) -> None:
    rng = np.random.default_rng(seed)
    samples = scale * rng.uniform(-1, 1, (n, f + 1, 2))
    samples[rng.random((n, f + 1)) < unknown] = np.nan  # agents out of view
    if infinite and n:
        samples[rng.integers(n), rng.integers(f + 1), rng.integers(2)] = np.inf
    s = data.draw(st.integers(0, f * substeps))
    x = scale * rng.uniform(-1, 1, (s, 2))
    record, truth = _record(x, n), CBFTruth(samples=samples, dt=dt, substeps=substeps)
    want = _before(record, truth)
    assert _bits(sl.smallest_distance(record, truth)) == _bits(want)
    # the kernel's two forms (compiled, interpreted) and the numpy alternative
    for form in (sl._nearest, sl._nearest.py_func, sl._nearest_numpy):
        best, finite = form(samples, dt, substeps, x)
        assert finite == (want is not None)
        if want is not None:
            assert _bits(best) == _bits(want)
    collision, shortfall = (
        sl.CollisionLoss(d_c=0.3 * scale),
        sl.DistanceShortfallLoss(d_safe=0.6 * scale, d_c=0.3 * scale),
    )
    got_c, got_s = collision(record, truth, 0.0), shortfall(record, truth, 0.0)
    if want is None:
        assert got_c is None and got_s is None
    else:
        assert got_c == float(want < 0.3 * scale)
        expect = min(max((0.6 * scale - want) / (0.3 * scale), 0.0), 1.0)
        assert _bits(got_s) == _bits(expect)


def test_scored_agents_and_other_shapes_take_the_numpy_path() -> None:
    rng = np.random.default_rng(3)
    samples = rng.uniform(-5, 5, (3, 4, 2))
    x = rng.uniform(-5, 5, (6, 2))
    truth = CBFTruth(samples=samples, dt=0.4, substeps=2)
    scored = np.array([False, True, False])
    record = _record(x, 3, scored)
    assert sl.smallest_distance(record, truth) == _before(record, truth)
    assert sl.smallest_distance(record, truth) == float(
        np.min(sl.min_distances(_record(x, 3), truth)[:, 1])
    )
    # a truth with other rows than the record's agents: min_distances' numbers
    record = _record(x, 2)
    assert sl.smallest_distance(record, truth) == _before(record, truth)


def test_too_many_control_instants_still_raise() -> None:
    samples = np.zeros((2, 3, 2))
    record = _record(np.zeros((7, 2)), 2)  # 7 instants, 2 intervals x 3 substeps = 6
    with pytest.raises(ValueError, match="control instants need"):
        sl.smallest_distance(record, CBFTruth(samples=samples, dt=0.4, substeps=3))


def test_no_agent_or_no_instant_has_no_loss() -> None:
    truth = CBFTruth(samples=np.zeros((0, 3, 2)), dt=0.4, substeps=2)
    assert sl.smallest_distance(_record(np.zeros((4, 2)), 0), truth) is None
    truth = CBFTruth(samples=np.ones((2, 3, 2)), dt=0.4, substeps=2)
    assert sl.smallest_distance(_record(np.zeros((0, 2)), 2), truth) is None
    assert sl.CollisionLoss()(_record(np.zeros((0, 2)), 2), truth, 0.0) is None
    assert math.isclose(
        sl.smallest_distance(_record(np.zeros((1, 2)), 2), truth) or 0.0, math.sqrt(2.0)
    )
