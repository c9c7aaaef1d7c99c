"""The shortfall loss: the gap loss below 0, the shortfall in units of c above (capped)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control.core.monitor import AgentMonitor
from conformal_control.core.update_rules.fixed_eta import FixedEtaRule
from conformal_control.families.cbf.barriers import APFBarrier
from conformal_control.families.cbf.constraint import ConformalConstraint
from conformal_control.families.cbf.loss import (
    SHORTFALL_CAP,
    CBFGapLoss,
    CBFShortfallLoss,
    gap_test_inputs,
)
from conformal_control.families.cbf.safe_lambda import derive_lambda_safe

C = 30.0


def _losses():
    con = ConformalConstraint(APFBarrier(K_rep=0.2, rho0=16.0, d_c=1.0), a=100.0)
    return con, CBFGapLoss(con, C), CBFShortfallLoss(con, C)


def test_its_values_on_a_constructed_gap_sequence():
    _, gap, sf = _losses()
    r = np.array([-math.inf, -60.0, -30.0, 0.0, 15.0, 60.0, 120.0, 200.0, math.inf])
    want = [-0.5, math.atan(-2.0) / math.pi, -0.25, 0.0, 0.5, 2.0, 4.0, 4.0, 4.0]
    assert np.allclose(sf.squash(r), want)
    # below 0 it is the gap loss bit for bit; above it the gap loss saturates at 1/2
    assert np.array_equal(sf.squash(r[:4]), gap.squash(r[:4]))
    assert float(gap.squash(60.0)) < 0.36 < float(sf.squash(60.0))
    assert SHORTFALL_CAP == 4.0 and sf.bounds == (-0.5, 4.0)
    assert isinstance(sf.squash(15.0), float)


def test_a_big_miss_moves_lambda_by_the_shortfall():
    """With eta = c the fixed-eta rule moves lambda by the shortfall itself (minus eta
    epsilon); the gap loss by at most eta (1/2 - epsilon)."""
    _, gap, sf = _losses()
    for top, lam in ((90.0, -30.0), (75.0, -10.0)):
        rule_sf = FixedEtaRule(epsilon=-0.05, eta=C, lambda_init=lam)
        rule_gap = FixedEtaRule(epsilon=-0.05, eta=C, lambda_init=lam)
        rule_sf.reset(), rule_gap.reset()
        shortfall = top + lam
        after_sf = rule_sf.update(float(sf.squash(shortfall)))
        after_gap = rule_gap.update(float(gap.squash(shortfall)))
        assert after_sf == pytest.approx(lam - shortfall - C * 0.05)
        assert lam - after_gap < C * 0.55 < lam - after_sf


def test_it_splits_by_agent_like_the_gap_loss():
    _, gap, sf = _losses()
    for record, truth in gap_test_inputs():
        lam = np.linspace(-40.0, 5.0, record.ids.size)
        a, b = gap.components(record, truth, lam), sf.components(record, truth, lam)
        assert np.array_equal(a.keys, b.keys)
        top = gap.gaps(record, truth)
        if not top.size or not np.isfinite(top).any():
            continue
        r = np.nanmax(top, axis=0) + lam
        assert np.allclose(b.values, sf.squash(r), equal_nan=True)
        # the counterfactual at another lambda is the shortfall loss's too
        assert b.at(0, -100.0) == pytest.approx(float(sf.squash(r[0] - lam[0] - 100.0)))


def test_lambda_safe_holds_for_it_with_its_own_level():
    """The derivation needs only a loss increasing in gap + lambda: lambda_safe = r_eps - G
    with r_eps the loss's level; at lambda_safe the worst gap G scores exactly epsilon."""
    con, _, sf = _losses()
    for eps in (-0.2, -0.05, 0.0, 0.1, 0.3):
        safe = derive_lambda_safe(con, C, eps, 2.0, level=sf.level(eps))
        g = safe.gap_bound
        assert float(sf.squash(g + safe.value)) == pytest.approx(eps, abs=1e-12)
        assert float(sf.squash(g + safe.value + 1e-6)) > eps
        if eps <= 0:  # the gap loss's lambda_safe
            assert safe.value == derive_lambda_safe(con, C, eps, 2.0).value
        else:  # c eps, not c tan(pi eps): the gap loss's formula would overshoot here
            assert sf.level(eps) == pytest.approx(C * eps)
            assert float(sf.squash(g + derive_lambda_safe(con, C, eps, 2.0).value)) > eps


def test_bad_targets_are_refused_in_one_line():
    _, gap, sf = _losses()
    for loss, eps, msg in (
        (sf, 4.5, r"epsilon must lie in \(-0.5, 4\) for the CBFShortfallLoss, got 4.5"),
        (sf, -0.5, r"epsilon must lie in \(-0.5, 4\)"),
        (gap, 0.5, r"epsilon must lie in \(-0.5, 0.5\) for the CBFGapLoss"),
    ):
        with pytest.raises(ValueError, match=msg) as err:
            loss.level(eps)
        assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match="level must be a finite number"):
        derive_lambda_safe(gap.constraint, C, -0.05, 2.0, level=math.inf)


def test_the_monitor_learns_per_agent_from_it():
    """A stale agent's big misses move its lambda faster than the gap loss would."""
    _, gap, sf = _losses()
    out = {}
    for name, loss in (("gap", gap), ("shortfall", sf)):
        mon = AgentMonitor(FixedEtaRule(epsilon=-0.05, eta=C), bounds=loss.bounds)
        for _ in range(3):
            lam = mon.values([1, 2])
            mon.update([1, 2], loss.squash(np.array([90.0, 0.0]) + lam))
        out[name] = mon.values([1, 2])
    assert out["shortfall"][0] < out["gap"][0] - 30.0
    assert out["shortfall"][1] == out["gap"][1]  # the well-predicted agent: the same
