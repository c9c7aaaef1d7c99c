"""A sampling-MPC family for your own simulator or robot, one call at a time.

:class:`StepwiseMPC` is :class:`~conformal_control.families.cbf.stepwise.StepwiseCBF` with a
planning decision family (``mpc``, ``acp_mpc``, ``ecp_mpc``) in place of the CBF
controller: the same calls, the same input contract, the same timing::

    ctrl = StepwiseMPC(family="mpc", stream=Stream(tau=0.4, dt=0.1, substeps=4))
    for k in range(n_samples):                    # sensor samples, every dt seconds
        ctrl.observe(ids, positions, t=k * dt)    # agents seen at this sample (m)
        for j in range(ctrl.substeps):            # control instants, every dt/substeps
            u = ctrl.step(ego_state, t=k * dt + j * ctrl.dt_control, goal=goal)
            ego_state = my_robot.apply(u)

:meth:`~StepwiseMPC.step` returns the plant's command (a velocity in m/s for the default
``velocity_tracking`` plant; (v, omega) for the ``unicycle``), and takes the plant's
state (``dynamics.state_dim`` numbers: x, y, vx, vy, and the heading for a unicycle).
Every ``tau`` seconds the interval that ends is scored with the family's loss on the
samples observed since (``distance_shortfall`` for ``mpc``, the miscoverage of its
regions for ``acp_mpc`` and ``ecp_mpc``) and lambda updated; the predictor forecasts the
sensed agents over the plan's horizon. The rule's ``epsilon``, ``eta`` and
``lambda_min`` default to the family's (as in a run), not the CBF's.
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np

from ...core import registry
from ...core.base import DecisionFamily, Loss, UpdateRule, param_names
from ...core.exceptions import ConformalControlDeprecationWarning, InputError
from ...core.loop import ConformalStepper
from ...core.spec import RunContext
from ...core.update_rules.base import check_epsilon, check_finite, check_positive
from ...predictors.base import Predictor
from ..cbf.controller import ConformalCBFController
from ..cbf.reference import AttractiveField
from ..cbf.roles import Dynamics, ReferenceController
from ..cbf.stepwise import StepwiseCBF, Stream, reject_unknown, stream_from

__all__ = ["StepwiseMPC"]


def _number(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.number)):
        raise InputError(f"{name} must be a finite number, got {value!r}")
    return check_finite(name, float(value))


def _moved(legacy: dict[str, Any], name: str, new: str) -> Any:
    """Pop a former keyword of :class:`StepwiseMPC` with a ``DeprecationWarning``."""
    if name not in legacy:
        return None
    warnings.warn(
        f"StepwiseMPC({name}=...) is deprecated: give {new} "
        "(removed in 0.4, not before 2027-06-30)",
        ConformalControlDeprecationWarning,
        stacklevel=3,
    )
    return legacy.pop(name)


class StepwiseMPC(StepwiseCBF):
    """A conformal sampling-MPC family driven by your own loop (SI units throughout).

    Parameters
    ----------
    predictor : Predictor or str
        A predictor instance or a registered name.
    family : str, (str, dict) or DecisionFamily
        A registered planning family (``mpc``, ``acp_mpc``, ``ecp_mpc``), the registry's
        ``(name, params)`` form (``("mpc", {"sampling": Sampling(n_samples=200)})`` or
        ``("mpc", {"sampling__n_samples": 200})``), or an instance of one (then its own
        settings apply).
    dynamics : str, (str, dict) or Dynamics
        The plant the family plans with: a registered name, ``(name, params)``, or an
        instance.
    reference : ReferenceController, optional
        The reference the family seeds its samples with; default the attractive field
        with gain 1/s and ``v_max``.
    rule : UpdateRule, optional
        Default: the fixed-step rule with ``epsilon``, ``eta``, ``lambda_init``,
        ``lambda_min``, ``lambda_max``.
    loss : Loss, optional
        Default: the family's own loss (``distance_shortfall`` with a safety distance
        1 m beyond ``d_c`` for ``mpc``).
    epsilon, eta, lambda_min : float, optional
        The rule's target, step and floor; default the family's (for ``mpc``: 0.1, 0.2 m,
        -1 m). ``epsilon`` lies strictly inside the loss's range.
    lambda_init : float, optional
        lambda_1, in the family's unit (m for ``mpc``, a level for the others); default 0,
        or the nearest bound when 0 lies outside ``[lambda_min, lambda_max]`` (a family's
        ceiling below 0). A value given outside the bounds is an error.
    lambda_max : float, optional
        The ceiling; default the family's: its ``default_rule_params`` ceiling, and at
        most :meth:`SamplingMPC.lambda_ceiling
        <conformal_control.families.mpc.controller.SamplingMPC.lambda_ceiling>` (``margin`` for
        ``mpc``, whose lambda is a length: the safe distance never falls below ``d_c``).
    stream : Stream, optional
        Timing and sensing of the stream, as for
        :class:`~conformal_control.families.cbf.stepwise.StepwiseCBF`; its ``substeps`` are the
        family's too.
    d_c : float
        Collision distance robot-agent, centre to centre (m).
    v_max : float
        Speed bound (m/s) of the sampled commands and of the default reference, unless
        the family's params set ``limits``.
    seed : int
        The family's random state (its sampled plans).
    **legacy
        The former keywords, still accepted with a ``DeprecationWarning``: ``tau``,
        ``dt``, ``substeps``, ``sensing_radius``, ``history`` (give ``stream=``),
        ``family_params`` / ``dynamics_params`` (give ``(name, params)``), ``margin``
        (a family parameter), ``K_att`` (give ``reference=``).
    """

    def __init__(
        self,
        predictor: Predictor | str = "constant_velocity",
        *,
        family: str | tuple[str, dict[str, Any]] | DecisionFamily[Any, Any, Any, Any] = "mpc",
        dynamics: str | tuple[str, dict[str, Any]] | Dynamics = "velocity_tracking",
        reference: ReferenceController | None = None,
        rule: UpdateRule | None = None,
        loss: Loss[Any, Any] | None = None,
        epsilon: float | None = None,
        eta: float | None = None,
        lambda_init: float | None = None,
        lambda_min: float | None = None,
        lambda_max: float | None = None,
        stream: Stream | None = None,
        d_c: float = 1.0,
        v_max: float = 2.0,
        seed: int = 0,
        **legacy: Any,
    ) -> None:
        stream = stream_from(stream, legacy, "StepwiseMPC")
        family_params = _moved(legacy, "family_params", "family=(name, params)")
        dynamics_params = _moved(legacy, "dynamics_params", "dynamics=(name, params)")
        if "margin" in legacy:
            margin = _moved(legacy, "margin", "family=(name, {'margin': ...})")
            family_params = {"margin": margin, **(family_params or {})}
        K_att = 1.0
        if "K_att" in legacy:
            K_att = _moved(legacy, "K_att", "reference=AttractiveField(K_att=..., v_max=...)")
        reject_unknown("StepwiseMPC", legacy)
        if isinstance(family, tuple):
            family, own = family
            family_params = {**(family_params or {}), **dict(own)}
        if isinstance(dynamics, tuple):
            dynamics, own = dynamics
            dynamics_params = {**(dynamics_params or {}), **dict(own)}
        for name, value in (("v_max", v_max), ("K_att", K_att)):
            check_positive(name, _number(name, value))
        check_positive("d_c", _number("d_c", d_c), allow_zero=True)
        self.tau_samples = stream.check()
        substeps = int(stream.substeps)

        pred: Predictor = (
            registry.create("predictor", predictor) if isinstance(predictor, str) else predictor
        )
        plant: Dynamics = (
            registry.create("dynamics", dynamics, **(dynamics_params or {}))
            if isinstance(dynamics, str)
            else dynamics
        )
        if not isinstance(dynamics, str) and dynamics_params:
            raise ValueError("dynamics_params apply to a plant given by name, not to an instance")
        ref = reference if reference is not None else AttractiveField(K_att, v_max)
        # the stream's values, each handed only to a plugin that declares it
        context = RunContext(
            collision_distance=d_c,
            safe_distance=d_c + 1.0,
            v_max=v_max,
            substeps=substeps,
            seed=seed,
            predictor=pred,
            dynamics=plant,
            reference=ref,
        )
        policy: DecisionFamily[Any, Any, Any, Any]
        if isinstance(family, str):
            cls = registry.get("family", family)
            if issubclass(cls, ConformalCBFController) or "dynamics" not in param_names(cls):
                raise InputError(
                    f"StepwiseMPC runs a planning family (one taking a predictor and a plant, "
                    f"as mpc, acp_mpc, ecp_mpc do), not {family!r}; use StepwiseCBF for the CBF"
                )
            registry.check_params("family", family, cls, dict(family_params or {}))
            policy = cls(**context.arguments(cls, family_params))
        elif isinstance(family, DecisionFamily):
            if family_params:
                raise ValueError(
                    "family_params apply to a family given by name, not to an instance"
                )
            policy = family
        else:
            raise InputError(
                f"family must be a registered name or a DecisionFamily, got {family!r}"
            )
        fam_substeps = getattr(policy, "substeps", int(substeps))
        if fam_substeps != substeps:
            raise ValueError(
                f"the family plans with substeps={fam_substeps}, the stream has "
                f"substeps={substeps}: give the same number of control instants per sample"
            )

        if loss is None:
            name = policy.capabilities.default_loss or "distance_shortfall"
            loss = registry.create("loss", name, **context.arguments(registry.get("loss", name)))
        defaults = dict(policy.capabilities.default_rule_params)
        if rule is None:
            eps = _number("epsilon", defaults.get("epsilon", 0.0) if epsilon is None else epsilon)
            step = _number("eta", defaults.get("eta", 1.0) if eta is None else eta)
            check_positive("eta", step, allow_zero=True)
            floor = defaults.get("lambda_min", -math.inf) if lambda_min is None else lambda_min
            if lambda_max is None:  # the family's (mpc: its ceiling, the safe distance >= d_c)
                ceiling = getattr(policy, "lambda_ceiling", None)
                margin = getattr(policy, "margin", 0.0)
                lambda_max = float(defaults.get("lambda_max", math.inf))
                if callable(ceiling) and isinstance(margin, (int, float)) and margin >= 0:
                    lambda_max = min(lambda_max, float(ceiling(float(margin))))
            check_epsilon(eps, loss.bounds)
            from ...core.update_rules import FixedEtaRule

            rule = FixedEtaRule(
                epsilon=eps,
                eta=step,
                lambda_init=(
                    min(max(0.0, float(floor)), float(lambda_max))
                    if lambda_init is None
                    else check_finite("lambda_init", lambda_init)
                ),
                lambda_min=float(floor),
                lambda_max=float(lambda_max),
            )
            learn = step > 0
        else:
            target = getattr(rule, "epsilon", None)
            if target is not None:
                check_epsilon(target, loss.bounds)
            learn = True

        # the stream (StepwiseCBF's observe/step/finish read these)
        self.stream = stream
        self.dt = float(stream.dt)
        self.substeps = substeps
        self.dt_control = self.dt / self.substeps
        self.sensing_radius = float(stream.sensing_radius)
        self.history = int(stream.history)
        self.dynamics = plant
        self.planner = policy
        self.stepper = ConformalStepper(policy, loss, rule, learn=learn)
        self.stepper.start()
        self._samples: dict[int, dict[int, np.ndarray]] = {}
        self._latest: int | None = None
        self._start: int | None = None
        self._sensed = np.zeros(0, dtype=np.int64)
        self._step = 0

    @property
    def state_dim(self) -> int:
        """Numbers in the ego state :meth:`step` takes (the plant's state)."""
        return int(self.dynamics.state_dim)

    def stats(self) -> dict[str, float]:
        """Counters of the family (plans, infeasible steps, fallbacks)."""
        return self.planner.stats()
