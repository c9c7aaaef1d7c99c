"""Build the flagship from a scene and parameters: every role an instance or a name.

One builder is used by the Python front door, the CLI, sweeps and the benchmark. Each
role -- predictor, barrier, safety filter, fallback, reference controller, dynamics, loss,
update rule -- is given as

* an instance (used as given, SI units), or
* a registered name (``conformal-control plugins``) built with ``<role>_params``, or
* ``None``: the flagship's default built from the run's parameters.

A plugin receives the run's values (SI) for the constructor arguments its class declares
in its capabilities (``run_values``: argument -> a name of
:data:`~conformal_control.core.spec.RUN_VALUES`, e.g. the APF barrier's ``{"d_c":
"barrier_distance", ...}``) and the caller did not give; nothing else (an argument that
merely shares a name with a run value keeps the plugin's own default). The flagship's
defaults are built the same way, by their registered names. Update-rule parameters are
typed in the scene's units (see :func:`build_rule`).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from dataclasses import dataclass, field
from typing import Any

from ..core import registry
from ..core.base import (
    CompiledForm,
    DecisionFamily,
    Loss,
    Plugin,
    UpdateRule,
    flat_params,
    param_names,
)
from ..core.exceptions import ConformalControlDeprecationWarning
from ..core.spec import RunContext, RunSpec
from ..core.update_rules import FixedEtaRule
from ..data.scene import Scene
from ..families.cbf.constraint import ConformalConstraint
from ..families.cbf.controller import ConformalCBFController
from ..families.cbf.feasibility import DEFAULT_FLOOR_SHARE, default_lambda_min
from ..families.cbf.roles import Barrier, Dynamics, ReferenceController, SafetyFilter
from ..predictors.base import Predictor
from ..world.reactive import make_environment
from ..world.replay import ReplayEnvironment
from .params import ResolvedParams, resolve_params

__all__ = ["Flagship", "RoleSpec", "build_flagship", "build_rule", "role_name"]

#: A role given as an instance, a registered name, or None (the default).
RoleSpec = Plugin | str | None


@dataclass
class Flagship:
    """The wired flagship: environment, decision family, loss, rule and their parts.

    Attributes
    ----------
    scene : Scene
        A copy of the caller's scene carrying the resolved radii, goal radius and v_max
        (the caller's scene is never modified).
    params : ResolvedParams
        The run's parameters as given, as used (scene units) and in SI.
    names : dict
        role -> the registered name it was built from, or the class name of an instance.
    """

    scene: Scene
    params: ResolvedParams
    env: ReplayEnvironment  # a ReactiveEnvironment for a reactive crowd
    # a ConformalCBFController (the compiled engine and the shield need one and check), or
    # a family that plans with the plant (the MPC families, a floor up): typed by duck
    family: Any
    loss: Loss[Any, Any]
    rule: UpdateRule
    constraint: ConformalConstraint
    predictor: Predictor
    barrier: Barrier
    safety_filter: SafetyFilter
    reference: ReferenceController
    dynamics: Dynamics
    names: dict[str, str] = field(default_factory=dict)

    @property
    def policy(self) -> Any:
        """Deprecated name of :attr:`family` (removed in 0.4, not before 2027-06-30)."""
        warnings.warn(
            "Flagship.policy is now Flagship.family (removed in 0.4, not before 2027-06-30)",
            ConformalControlDeprecationWarning,
            stacklevel=2,
        )
        return self.family

    def _parts(self) -> dict[str, Any]:
        """role -> the plugin that fills it (the rule last: it has no compiled form)."""
        return {
            "predictor": self.predictor,
            "barrier": self.barrier,
            "safety_filter": self.safety_filter,
            "reference": self.reference,
            "dynamics": self.dynamics,
            "loss": self.loss,
            "rule": self.rule,
        }

    def compiled_forms(self) -> dict[str, CompiledForm | None]:
        """The compiled form of each part, as the compiled engine reads it: role ->
        ``compiled_state()`` (None for a part that hands none); after :meth:`reset`."""
        parts = self._parts()
        del parts["rule"]
        return {role: part.compiled_state() for role, part in parts.items()}

    def role_params(self) -> dict[str, dict[str, Any]]:
        """role -> ``{"name": ..., "params": get_params()}`` (for config.json)."""
        roles = self._parts()
        out = {
            role: {"name": self.names.get(role, type(obj).__name__), "params": flat_params(obj)}
            for role, obj in roles.items()
        }
        parts = ("predictor", "constraint", "safety_filter", "reference")
        out["family"] = {
            "name": self.names.get("family", type(self.family).__name__),
            "params": {k: v for k, v in flat_params(self.family).items() if k not in parts},
        }
        return out


def _plans_with_a_plant(cls: type) -> bool:
    """Whether a decision family is built from a predictor and the robot's plant (the
    MPC families: ``predictor=``, ``dynamics=``)."""
    names = set(param_names(cls))
    return {"predictor", "dynamics"} <= names


def role_name(spec: RoleSpec, default: str) -> str:
    """The name recorded for a role: the registered name, the class name, or ``default``."""
    if spec is None:
        return default
    if isinstance(spec, str):
        return spec
    return type(spec).__name__


def _create(role: str, name: str, given: dict[str, Any] | None, context: RunContext) -> Any:
    """``registry.create`` with the run values the plugin declares and the caller left out."""
    return registry.create(role, name, **context.arguments(registry.get(role, name), given))


def _resolve(
    role: str,
    spec: RoleSpec,
    given: dict[str, Any] | None,
    context: RunContext,
    base: type,
) -> Any | None:
    """An instance for ``spec``: None stays None (caller builds the default)."""
    if spec is None:
        if given:
            raise ValueError(f"{role}_params given without a {role} name")
        return None
    if isinstance(spec, str):
        return _create(role, spec, given, context)
    if given:
        raise ValueError(f"{role}_params apply to a {role} given by name, not to an instance")
    if not isinstance(spec, base):
        raise TypeError(
            f"{role} must be a registered name or a {base.__name__} instance, "
            f"got {type(spec).__name__}"
        )
    return spec


def build_rule(
    name: str, rule_params: dict[str, Any] | None, params: ResolvedParams, lam_unit: float
) -> UpdateRule:
    """A registered update rule for the flagship, from the run's parameters.

    The rule receives ``epsilon``, ``eta``, ``lambda_init``, ``lambda_min`` and
    ``lambda_max`` from the run's parameters (SI) for the constructor arguments its
    capabilities declare (``run_values``); ``rule_params`` (in the scene's units) override
    them and add the rule's own parameters. Parameters the rule declares in
    ``lambda_params`` (units of lambda, e.g. ``eta``, ``K_I``, ``gammas``) are converted
    with ``lam_unit``.

    Parameters
    ----------
    name : str
        The rule's registered name.
    rule_params : dict, optional
        Its parameters, in the scene's units.
    params : ResolvedParams
        The run's parameters.
    lam_unit : float
        SI value of one unit of lambda as ``rule_params`` are typed (1 for SI).
    """
    cls = registry.get("rule", name)
    si = params.si
    kwargs = RunContext(
        epsilon=si["epsilon"],
        eta=si["eta"],
        lambda_init=si["lambda_init"],
        lambda_min=si["lambda_min"],
        lambda_max=si["lambda_max"],
    ).arguments(cls)
    user = dict(rule_params or {})
    registry.check_params("rule", name, cls, user)
    lam_params = set(cls.capabilities.lambda_params)
    for k, v in user.items():
        if isinstance(v, str) and "," in v:  # a list from the command line: "0.1,1,10"
            v = [float(x) for x in v.split(",") if x.strip()]
        if k in lam_params and v is not None:
            v = [x * lam_unit for x in v] if isinstance(v, (list, tuple)) else v * lam_unit
        kwargs[k] = v
    init, floor = kwargs.get("lambda_init"), kwargs.get("lambda_min")
    if (
        "lambda_init" in user
        and "lambda_min" not in user
        and "lambda_min" not in params.given
        and isinstance(init, (int, float))
        and isinstance(floor, (int, float))
    ):
        # a default floor never overrides the rule's own initial lambda (see build_flagship)
        kwargs["lambda_min"] = min(float(floor), float(init))
    lo, hi = kwargs.get("lambda_min"), kwargs.get("lambda_max")
    if (
        "lambda_init" not in user
        and "lambda_init" not in params.given
        and all(isinstance(x, (int, float)) for x in (init, lo, hi))
    ):
        # bounds given to the rule by name: a default initial lambda starts inside them
        kwargs["lambda_init"] = min(max(float(init), float(lo)), float(hi))  # type: ignore[arg-type]
    rule: UpdateRule = registry.create("rule", name, **kwargs)
    return rule


def build_flagship(
    scene: Scene,
    spec: RunSpec | dict[str, Any] | ResolvedParams | None = None,
    **settings: Any,
) -> Flagship:
    """Wire the conformal CBF controller on ``scene`` as ``spec`` says.

    Parameters
    ----------
    scene : Scene
    spec : RunSpec, dict or ResolvedParams, optional
        The run (:class:`~conformal_control.core.spec.RunSpec`); a dict is its ``params`` (in
        its ``units``), a :class:`ResolvedParams` parameters already resolved.
    **settings
        Settings of the run applied on ``spec``
        (:meth:`RunSpec.from_settings <conformal_control.core.spec.RunSpec.from_settings>`):
        ``predictor``, ``barrier``, ``safety_filter``, ``fallback``, ``reference``,
        ``dynamics``, ``loss``, ``rule``, ``family``, ``crowd`` (each an instance, a
        registered name, ``(name, params)`` or None for the flagship's default: the
        paper's APF barrier, the exact 2-D filter ``exact2d`` with the run's fallback, the
        attractive-field reference, the velocity-tracking double integrator, the
        ``cbf_gap`` loss, the ``fixed_eta`` rule, the ``cbf`` family, the replayed crowd),
        ``<role>_params``, ``units``, ``learn``, ``seed``, ``max_frames``.

    Notes
    -----
    ``fallback`` is handed to the safety filter's ``fallback`` argument. ``family``
    ``"acp"`` is adaptive conformal prediction regions
    (:class:`~conformal_control.families.cbf.acp.ACPController`). A family built from a predictor
    and the plant (the sampling MPCs ``"mpc"``, ``"acp_mpc"``, ``"ecp_mpc"``,
    :mod:`conformal_control.families.mpc`) receives the predictor, the dynamics, the reference,
    ``d_c`` (robot + agent radius), ``margin`` (``barrier_margin``), ``v_max``,
    ``substeps`` and ``random_state`` (the seed) for the arguments it takes, then the
    family's parameters; its loss defaults to the family's ``default_loss`` (with
    ``d_safe`` = ``d_c`` + 1 m where the loss takes one), its rule's ``epsilon`` and
    ``eta`` to the family's ``default_rule_params`` unless the run gives them, and the
    rule's parameters are in SI (its lambda is a length or a level, not a rate). The
    parameters of ``rule`` are otherwise in ``units``, those of every other named plugin
    in SI. A reactive crowd's ``seed`` defaults to the run's.
    """
    resolved: ResolvedParams | None = None
    if isinstance(spec, ResolvedParams):
        resolved, spec = spec, None
    if isinstance(spec, RunSpec):
        run = RunSpec.from_settings(None, base=spec, **settings) if settings else spec
    else:
        run = RunSpec.from_settings(spec, **settings)
    return _build(scene, run, resolved)


def _build(scene: Scene, run: RunSpec, resolved: ResolvedParams | None) -> Flagship:
    """:func:`build_flagship` on a complete specification."""
    units, learn, seed, max_frames = run.units, run.learn, run.seed, run.max_frames
    predictor, predictor_params = run.role("predictor")
    barrier, barrier_params = run.role("barrier")
    safety_filter, safety_filter_params = run.role("safety_filter")
    fallback, fallback_params = run.role("fallback")
    reference, reference_params = run.role("reference")
    dynamics, dynamics_params = run.role("dynamics")
    loss, loss_params = run.role("loss")
    rule, rule_params = run.role("rule")
    family, family_params = run.role("family")
    crowd, crowd_params = run.role("crowd")
    if fallback_params:  # a fallback with its own parameters: built here, by name
        fallback = registry.create("fallback", fallback, **fallback_params)
    if resolved is None:
        from .params import to_scene_units

        given = to_scene_units(scene, dict(run.params), units)
        if not learn:
            given.setdefault("eta", 0.0)
        resolved = resolve_params(scene, given)
    si = resolved.si
    d_c = si["robot_radius"] + si["agent_radius"]
    # The environment reads radii and v_max from the scene: give it a copy carrying the
    # resolved values, never mutate the caller's scene (runs may share one in a process).
    scene = scene.replace(
        robot_radius=si["robot_radius"],
        agent_radius=si["agent_radius"],
        goal_radius=si["goal_radius"],
        v_max=si["v_max"],
    )
    names: dict[str, str] = {}
    fallback_value: Any = "lambda_search" if fallback is None else fallback
    if fallback is not None and not isinstance(fallback, str):
        names["fallback"] = type(fallback).__name__
    else:
        names["fallback"] = str(fallback_value)
    # the run's values, each handed only to a plugin that declares it (RunContext)
    context = RunContext(
        collision_distance=d_c,
        barrier_distance=d_c + si["barrier_margin"],
        safe_distance=d_c + 1.0,
        barrier_margin=si["barrier_margin"],
        v_max=si["v_max"],
        K_att=si["K_att"],
        K_acc=si["K_acc"],
        K_rep=si["K_rep"],
        rho0=si["rho0"],
        convention=si["convention"],
        delta=si["delta"],
        speed_sides=si["speed_sides"],
        substeps=si["substeps"],
        loss_scale=si["loss_scale"],
        seed=seed,
        fallback=fallback_value,
    )

    pred = _resolve("predictor", predictor, predictor_params, context, Predictor)
    if pred is None:
        pred = _create("predictor", "constant_velocity", None, context)
    names["predictor"] = role_name(predictor, "constant_velocity")

    bar = _resolve("barrier", barrier, barrier_params, context, Barrier)
    if bar is None:
        bar = _create("barrier", "apf", None, context)
    names["barrier"] = role_name(barrier, "apf")
    # the edge rule on the true collision distance (barrier_margin is the barrier's only)
    constraint = ConformalConstraint(
        bar,
        a=si["a"],
        edge=si["edge"],
        collision_distance=d_c,
        escape_margin=si["escape_margin"],
    )
    context = context.replace(constraint=constraint)

    filt = _resolve("safety_filter", safety_filter, safety_filter_params, context, SafetyFilter)
    if filt is None:
        filt = _create("safety_filter", "exact2d", None, context)
    names["safety_filter"] = role_name(safety_filter, "exact2d")

    ref = _resolve("reference", reference, reference_params, context, ReferenceController)
    if ref is None:
        ref = _create("reference", "attractive_field", None, context)
    names["reference"] = role_name(reference, "attractive_field")

    dyn = _resolve("dynamics", dynamics, dynamics_params, context, Dynamics)
    if dyn is None:
        dyn = _create("dynamics", "velocity_tracking", None, context)
    names["dynamics"] = role_name(dynamics, "velocity_tracking")
    context = context.replace(predictor=pred, safety_filter=filt, reference=ref, dynamics=dyn)

    fam_name = family or "cbf"
    fam_cls = registry.get("family", fam_name)
    planning = not issubclass(fam_cls, ConformalCBFController)
    if planning and not _plans_with_a_plant(fam_cls):
        raise TypeError(
            f"decision family {fam_name!r} is neither built from the flagship's parts (a "
            "ConformalCBFController subclass) nor from a predictor and a plant (a family "
            "taking predictor= and dynamics=, as the MPC families do)"
        )
    # an MPC family's loss defaults to its own (a safety distance 1 m beyond collision)
    loss_obj = _resolve("loss", loss, loss_params, context, Loss)
    default_loss = fam_cls.capabilities.default_loss or "cbf_gap"
    if loss_obj is None:
        loss_obj = _create("loss", default_loss, None, context)
    names["loss"] = role_name(loss, default_loss)

    rule_resolved = resolved
    if not planning and "lambda_min" not in resolved.given and si["edge"] == "escape":
        # the CBF's default lambda floor (issue 30): a share of the feasibility floor,
        # never above the run's own lambda_init (a default never overrides a value the
        # run gave: a fixed lambda of -45/s runs at -45/s, not at the floor)
        default_floor = default_lambda_min(float(si["a"]), bar.upper_bound)
        floor = min(default_floor, float(si["lambda_init"]))
        if si["lambda_min"] < floor <= si["lambda_max"]:
            in_scene = floor / scene.units.factor("lambda_min")
            why = (
                f"the default floor ({DEFAULT_FLOOR_SHARE:g} x the feasibility floor -a h_max)"
                if floor == default_floor
                else "the run's lambda_init (above it the default floor would move it)"
            )
            resolved = dataclasses.replace(
                resolved,
                si={**si, "lambda_min": floor},
                scene_units={**resolved.scene_units, "lambda_min": in_scene},
                notes=[
                    *resolved.notes,
                    f"lambda_min: {in_scene:g}, {why}",
                ],
            )
            rule_resolved = resolved
    if planning:
        # the scene's epsilon and eta are for the CBF's gap loss: an MPC family's own
        # defaults apply unless the run gave them
        fam_defaults = dict(fam_cls.capabilities.default_rule_params)
        ceiling = getattr(fam_cls, "lambda_ceiling", None)
        margin = dict(family_params or {}).get("margin", si["barrier_margin"])
        if callable(ceiling) and isinstance(margin, (int, float)) and margin >= 0:
            # lambda never pushes the safe distance below d_c (SamplingMPC.lambda_ceiling)
            top = float(ceiling(float(margin)))
            if math.isfinite(top):
                fam_defaults.setdefault("lambda_max", top)
        own = {k: v for k, v in fam_defaults.items() if k not in resolved.given}
        if own:
            # the run's parameters are these (config.json, metrics): lambda's unit is the
            # family's in the scene's units too (a length or a level, not a rate)
            rule_resolved = dataclasses.replace(
                resolved,
                si={**si, **own},
                scene_units={**resolved.scene_units, **own},
                notes=[
                    *resolved.notes,
                    f"{', '.join(sorted(own))}: the {fam_name} family's defaults "
                    f"({', '.join(f'{k}={v:g}' for k, v in sorted(own.items()))}), not the "
                    "scene's (which are the CBF's)",
                ],
            )
            resolved = rule_resolved
    rsi = rule_resolved.si
    if "lambda_init" not in rule_resolved.given and not (
        rsi["lambda_min"] <= rsi["lambda_init"] <= rsi["lambda_max"]
    ):
        # a default lambda_init outside bounds the run or the family set (an MPC family's
        # ceiling below 0): start at the nearest bound, said in the run's notes; a
        # lambda_init the run gave is never moved (the rule refuses it at reset)
        start = min(max(rsi["lambda_init"], rsi["lambda_min"]), rsi["lambda_max"])
        in_scene = start if planning else start / scene.units.factor("lambda_init")
        same = resolved is rule_resolved
        rule_resolved = dataclasses.replace(
            rule_resolved,
            si={**rsi, "lambda_init": start},
            scene_units={**rule_resolved.scene_units, "lambda_init": in_scene},
            notes=[
                *rule_resolved.notes,
                f"lambda_init: {start:g} (SI), the default {rsi['lambda_init']:g} moved into "
                f"[lambda_min, lambda_max] = [{rsi['lambda_min']:g}, {rsi['lambda_max']:g}]",
            ],
        )
        if same:
            resolved = rule_resolved
    if isinstance(rule, str):
        # an MPC family's lambda is a length or a level, never in the scene's time unit
        lam_unit = 1.0 if units == "si" or planning else scene.units.factor("lambda_init")
        rule_obj = build_rule(rule, rule_params, rule_resolved, lam_unit)
    elif rule is None:
        rule_obj = FixedEtaRule(
            epsilon=rule_resolved.si["epsilon"],
            eta=rule_resolved.si["eta"],
            lambda_init=rule_resolved.si["lambda_init"],
            lambda_min=rule_resolved.si["lambda_min"],
            lambda_max=rule_resolved.si["lambda_max"],
        )
    else:
        if rule_params:
            raise ValueError("rule_params apply to a rule given by name, not to an instance")
        if not isinstance(rule, UpdateRule):
            raise TypeError(f"rule must be a registered name or an UpdateRule, got {rule!r}")
        rule_obj = rule
    names["rule"] = role_name(rule, "fixed_eta")
    names["crowd"] = crowd

    registry.check_params("family", fam_name, fam_cls, dict(family_params or {}))
    policy: DecisionFamily[Any, Any, Any, Any] = fam_cls(
        **context.arguments(fam_cls, family_params)
    )
    names["family"] = fam_name
    cp = dict(crowd_params or {})
    if crowd != "replay":
        cp.setdefault("seed", seed)
    env = make_environment(
        scene,
        crowd,
        cp,
        dynamics=dyn,
        tau_frames=resolved.tau_frames,
        substeps=si["substeps"],
        sensing_radius=si["sensing_radius"],
        history_frames=resolved.history_frames,
        max_frames=max_frames,
    )
    return Flagship(
        scene=scene,
        params=resolved,
        env=env,
        family=policy,
        loss=loss_obj,
        rule=rule_obj,
        constraint=constraint,
        predictor=pred,
        barrier=bar,
        safety_filter=filt,
        reference=ref,
        dynamics=dyn,
        names=names,
    )
