"""The sampling MPC records the ego's position, velocity and command of each control
instant in place (rows of one array, grown when full) instead of lists of small arrays:
the interval's record holds the numbers the lists gave, for velocity and acceleration
plants and intervals longer than the first buffer."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control.families.cbf.dynamics import (
    DoubleIntegrator,
    VelocityTrackingDoubleIntegrator,
)
from conformal_control.families.cbf.records import ControlState
from conformal_control.families.cbf.reference import AttractiveField
from conformal_control.families.mpc import SamplingMPC
from conformal_control.families.mpc.settings import Limits, Sampling
from conformal_control.predictors import ConstantVelocityPredictor, PredictionQuery


@pytest.mark.parametrize("plant", ["velocity", "acceleration"])
@pytest.mark.parametrize("steps", [0, 1, 63, 64, 65, 150])
def test_the_record_holds_what_the_lists_held(plant: str, steps: int) -> None:
    dynamics = (
        VelocityTrackingDoubleIntegrator(K_acc=10.0) if plant == "velocity" else DoubleIntegrator()
    )
    mpc = SamplingMPC(
        ConstantVelocityPredictor(),
        dynamics,
        AttractiveField(K_att=1.0, v_max=1.5),
        sampling=Sampling(n_samples=40, horizon=5, dt_plan=0.3),
        d_c=1.0,
        limits=Limits(v_max=1.5),
        substeps=2,
    )
    mpc.reset()
    rng = np.random.default_rng(steps)
    hist = rng.uniform(-4, 4, (3, 1, 2)) + 0.1 * np.arange(5)[None, :, None]
    for _ in range(2):  # a second interval starts from an empty record
        mpc.begin_interval(PredictionQuery(ids=np.arange(3), history=hist, dt=0.1, horizon=80))
        xs, vs, cmds, lams = [], [], [], []
        x = np.r_[0.0, 0.0, 0.3, -0.2]
        for k in range(steps):
            state = ControlState(x=x.copy(), t=0.05 * k, step=k, goal=np.array([8.0, 0.0]))
            lam = float(rng.uniform(-0.5, 0.5))
            cmd = mpc.decide(state, lam)
            # the lists' form (controller.py at e43769b)
            xs.append(np.array(state.x[:2], dtype=float))
            vel = cmd if plant == "velocity" else dynamics.velocity(state.x)
            vs.append(np.array(vel, dtype=float))
            cmds.append(cmd)
            lams.append(lam if mpc._plan.status in ("optimal", "unconstrained") else math.nan)
            x = dynamics.step(x, cmd, 0.05)
        rec = mpc.interval_record()
        for got, want in (
            (rec.x_ego, np.array(xs).reshape(steps, 2)),
            (rec.v_ego, np.array(vs).reshape(steps, 2)),
            (rec.command, np.array(cmds).reshape(steps, 2)),
            (rec.lam_applied, np.array(lams, dtype=float)),
        ):
            assert got.shape == want.shape and got.dtype == want.dtype
            assert got.flags.c_contiguous
            assert got.tobytes() == want.tobytes()
        assert rec.status == [] if steps == 0 else len(rec.status) == steps


def test_records_do_not_share_the_buffer() -> None:
    mpc = SamplingMPC(
        ConstantVelocityPredictor(),
        VelocityTrackingDoubleIntegrator(K_acc=10.0),
        AttractiveField(K_att=1.0, v_max=1.5),
        sampling=Sampling(n_samples=20, horizon=3, dt_plan=0.3),
        limits=Limits(v_max=1.5),
    )
    mpc.reset()
    hist = np.zeros((1, 5, 2)) + 3.0
    records = []
    for k in range(2):
        mpc.begin_interval(PredictionQuery(ids=np.arange(1), history=hist, dt=0.1, horizon=4))
        state = ControlState(x=np.r_[float(k), 0.0, 0.0, 0.0], t=k, step=0, goal=np.r_[8.0, 0.0])
        mpc.decide(state, 0.0)
        records.append(mpc.interval_record())
    assert records[0].x_ego.tolist() == [[0.0, 0.0]]
    assert records[1].x_ego.tolist() == [[1.0, 0.0]]
