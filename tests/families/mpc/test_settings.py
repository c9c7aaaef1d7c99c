"""The MPC families' parameter groups: deep parameters, clone, the registry's
``(name, params)`` form, and the former flat keywords (a DeprecationWarning each)."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from conformal_control.core import registry
from conformal_control.core.base import flat_params
from conformal_control.families.cbf import StepwiseCBF, Stream
from conformal_control.families.cbf.dynamics import VelocityTrackingDoubleIntegrator
from conformal_control.families.mpc import (
    ACPMPC,
    ECPMPC,
    Costs,
    Limits,
    Sampling,
    SamplingMPC,
    StepwiseMPC,
)
from conformal_control.predictors.constant_velocity import ConstantVelocityPredictor
from conformal_control.testing import clone

FAMILIES = (SamplingMPC, ACPMPC, ECPMPC)


def make(cls: type = SamplingMPC, **kw):
    return cls(ConstantVelocityPredictor(), VelocityTrackingDoubleIntegrator(10.0), **kw)


@pytest.mark.parametrize("cls", FAMILIES)
def test_deep_parameters_read_and_set_a_groups_field(cls):
    fam = make(cls, costs=Costs(w_goal=2.0))
    deep = fam.get_params(deep=True)
    assert deep["costs__w_goal"] == 2.0 and deep["sampling__n_samples"] == 500
    assert "costs__w_goal" not in fam.get_params()  # shallow: the constructor's arguments
    before = fam.costs
    fam.set_params(costs__w_terminal=3.0, sampling__horizon=5)
    assert fam.costs == Costs(w_goal=2.0, w_terminal=3.0) and fam.sampling.horizon == 5
    assert before == Costs(w_goal=2.0)  # groups are frozen: replaced, never mutated
    with pytest.raises(ValueError, match="no field"):
        fam.set_params(costs__w_nothing=1.0)


@pytest.mark.parametrize("cls", FAMILIES)
def test_clone_and_flat_params_rebuild_the_same_family(cls):
    fam = make(cls, sampling=Sampling(n_samples=7, hold=1), limits=Limits(a_max=3.0))
    twin = clone(fam)
    assert twin.get_params(deep=True) == fam.get_params(deep=True)
    assert twin.sampling is fam.sampling or twin.sampling == fam.sampling
    flat = flat_params(fam)
    assert not any(isinstance(v, (Sampling, Costs, Limits)) for v in flat.values())
    json.dumps({k: v for k, v in flat.items() if k not in ("predictor", "dynamics")})
    rebuilt = cls(**flat)  # the deep form is a constructor's too (the registry's form)
    assert rebuilt.get_params(deep=True) == fam.get_params(deep=True)


def test_the_registry_builds_a_family_from_deep_parameters():
    fam = registry.create(
        "family",
        "mpc",
        predictor=ConstantVelocityPredictor(),
        dynamics=VelocityTrackingDoubleIntegrator(10.0),
        sampling__n_samples=9,
        costs__w_goal=0.5,
    )
    assert fam.sampling == Sampling(n_samples=9) and fam.costs == Costs(w_goal=0.5)
    with pytest.raises(registry.UnknownParameterError, match="did you mean 'sampling'"):
        registry.check_params("family", "mpc", SamplingMPC, {"samplin__n": 1})


@pytest.mark.parametrize(
    ("old", "group", "field"),
    [
        ("n_samples", "sampling", "n_samples"),
        ("horizon", "sampling", "horizon"),
        ("dt_plan", "sampling", "dt_plan"),
        ("hold", "sampling", "hold"),
        ("replan_every", "sampling", "replan_every"),
        ("v_max", "limits", "v_max"),
        ("a_max", "limits", "a_max"),
        ("w_goal", "costs", "w_goal"),
        ("w_terminal", "costs", "w_terminal"),
        ("w_effort", "costs", "w_effort"),
        ("w_comfort", "costs", "w_comfort"),
    ],
)
def test_a_former_flat_keyword_still_works_with_a_deprecation_warning(old, group, field):
    with pytest.warns(DeprecationWarning, match=f"give {group}=.*{group}__{field}"):
        fam = make(**{old: 3})
    assert getattr(getattr(fam, group), field) == 3
    with pytest.warns(DeprecationWarning, match=f"{group}__{field}"):
        assert getattr(fam, old) == 3  # reading the old attribute
    with pytest.warns(DeprecationWarning):
        fam.set_params(**{old: 4})
    assert getattr(getattr(fam, group), field) == 4


def test_old_and_new_forms_plan_the_same_commands():
    def commands(fam: SamplingMPC) -> np.ndarray:
        from conformal_control.families.cbf.controller import ControlState

        fam.reset()
        s = ControlState(x=np.zeros(4), t=0.0, step=0, goal=np.array([5.0, 1.0]))
        return fam.plan(s, 0.0).commands

    new = make(sampling=Sampling(n_samples=50, horizon=5), costs=Costs(w_comfort=0.2))
    with pytest.warns(DeprecationWarning):
        old = make(n_samples=50, horizon=5, w_comfort=0.2)
    np.testing.assert_array_equal(commands(new), commands(old))


def test_an_unknown_keyword_is_still_a_type_error():
    with pytest.raises(TypeError, match="unexpected keyword argument 'n_sample'"):
        make(n_sample=3)


def test_stepwise_controllers_take_the_stream_and_still_the_flat_keywords():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ctrl = StepwiseCBF(stream=Stream(tau=0.2, dt=0.1, substeps=2))
    assert (ctrl.dt, ctrl.substeps, ctrl.tau_samples) == (0.1, 2, 2)
    with pytest.warns(DeprecationWarning, match=r"stream=Stream\(tau=0.2, dt=0.1\)"):
        old = StepwiseCBF(tau=0.2, dt=0.1)
    assert old.stream == Stream(tau=0.2, dt=0.1)
    with pytest.raises(TypeError, match="unexpected keyword argument 'taux'"):
        StepwiseCBF(taux=0.2)


def test_stepwise_mpc_maps_its_former_keywords():
    with pytest.warns(DeprecationWarning) as seen:
        ctrl = StepwiseMPC(
            family="mpc",
            family_params={"n_samples": 20},
            dynamics_params={"K_acc": 5.0},
            margin=0.3,
            K_att=2.0,
            substeps=2,
        )
    said = " ".join(str(w.message) for w in seen)
    for new in ("family=(name, params)", "dynamics=(name, params)", "stream=Stream("):
        assert new in said
    fam = ctrl.planner
    assert fam.sampling.n_samples == 20 and fam.margin == 0.3 and fam.substeps == 2
    assert fam.reference.K_att == 2.0 and ctrl.dynamics.K_acc == 5.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        new = StepwiseMPC(
            family=("mpc", {"sampling": Sampling(n_samples=20), "margin": 0.3}),
            dynamics=("velocity_tracking", {"K_acc": 5.0}),
            stream=Stream(substeps=2),
            v_max=1.5,
        )
    assert new.planner.sampling.n_samples == 20 and new.planner.limits.v_max == 1.5
