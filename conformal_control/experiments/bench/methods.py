"""Benchmark methods: named, composable configurations of the flagship.

A :class:`Method` is a family name, a setting, and what it changes in the flagship: run
parameters (SI units: lambda and eta in 1/s, lengths in m), the update rule, and any role
given by registered name (barrier, safety filter, fallback, loss, predictor). Every
method runs through the same public builder (:func:`conformal_control.runs.build.build_flagship`
via :func:`conformal_control.runs.episode.run_episode`), so a user can reproduce any row of a
leaderboard with ``run_episode(scene, **method.run_kwargs(predictor))``.

Families are declared as data (:class:`Family`: roles by registered name, parameters, and
the one parameter its setting fills), one entry each in :data:`FAMILIES`; a plugin adds its
own with :func:`register_family`. The families (``conformal-control bench methods`` lists
them with their settings and tuning grids):

``nolearn``        lambda = 0, no learning (the paper's pred/noLearn)
``fixed``          a fixed lambda < 0 (a fixed-margin CBF), no learning
``conformal``      the paper's fixed-eta rule on the gap loss, over an epsilon grid
``conformal_pid``  conformal PID control (Angelopoulos et al. 2023) on the gap loss
``conformal_dtaci`` DtACI experts (Gibbs & Candes 2022) on the gap loss
``conformal_aci``  ACI's rule on the collision loss (target: a collision rate per interval)
``conformal_agent`` a lambda per pedestrian, each its own fixed-eta rule on its own gap loss
``conformal_agent_dtaci`` a lambda per pedestrian, each its own DtACI experts
``conformal_agent_shortfall`` the same on the shortfall loss (a big miss moves lambda more)
``conformal_agent_floorstep`` per-pedestrian DtACI whose own floor steps down while it binds
``conformal_dtaci_floor`` DtACI experts with a lambda floor (the floor tuned)
``oracle``         the true future as prediction, lambda = 0 (the paper's gt/noLearn)
``inflated``       a robust CBF: d_c inflated by a fixed margin in the barrier, lambda = 0
``fallback:*``     ``conformal`` with another fallback (``brake``, ``relax``)
``acp``            adaptive conformal prediction regions (when registered)
``mpc``            the sampling MPC with a fixed safe distance (margin grid), no learning
``cc_mpc``         the CDT conformal controller: the sampling MPC learning its distance
``cc_mpc_margin``  the same learning its distance from the forecast's clearance error
``cc_mpc_margin_agent`` the same with a distance per pedestrian (lambda per pedestrian)
``cc_mpc_margin_agent_floor`` the same with a floor on each lambda (at most 0.2 m added)
``cc_mpc_margin_agent_interval`` each pedestrian's floored distance over one interval's plan steps
``oracle_mpc``     the sampling MPC planning with the true future, margin 0
``acp_mpc``        the sampling MPC avoiding ACP regions per plan step
``ecp_mpc``        the sampling MPC avoiding egocentric conformal regions
``fcp_mpc``        the sampling MPC against conformalized distance fields (online calibration)

The MPC families are not in the default method set (``--methods mpc,cc_mpc,...``).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from ...core.spec import RunSpec

__all__ = [
    "DEFAULT_METHODS",
    "FAMILIES",
    "FRAME",
    "METHOD_FAMILIES",
    "Family",
    "Method",
    "available",
    "expand_methods",
    "register_family",
]

#: One video frame of SDD (30 fps) in seconds: the paper's unit of lambda is 1/frame.
FRAME = 1.0 / 30.0


def _frozen(d: Mapping[str, Any] | None) -> Mapping[str, Any]:
    return MappingProxyType(dict(d or {}))


@dataclass(frozen=True)
class Method:
    """One configuration of the flagship in the benchmark (SI units).

    Attributes
    ----------
    family : str
        Method family (``conformal``, ``fixed``, ...).
    setting : str
        What distinguishes this member of the family (e.g. ``eps=-0.1``).
    description : str
    learn : bool
        Whether lambda is learned.
    predictor : str or None
        A registered predictor replacing the benchmark's (the oracle), else None.
    params : mapping
        Run parameters in SI (``epsilon``, ``eta``, ``lambda_init``, ``barrier_margin``...).
    rule : str
        Registered update rule.
    rule_params : mapping
        Its parameters (SI).
    roles : mapping
        role -> registered name, for ``barrier``, ``safety_filter``, ``fallback``,
        ``loss``, ``reference``, ``dynamics``.
    role_params : mapping
        role -> parameters (SI) of that named plugin.
    options : mapping
        Run options (:class:`~conformal_control.core.spec.RunSpec` fields that are no
        parameter and no role), e.g. ``{"lambda_safe": "auto"}``.
    """

    family: str
    setting: str = ""
    description: str = ""
    learn: bool = True
    predictor: str | None = None
    params: Mapping[str, Any] = field(default_factory=dict)
    rule: str = "fixed_eta"
    rule_params: Mapping[str, Any] = field(default_factory=dict)
    roles: Mapping[str, str] = field(default_factory=dict)
    role_params: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    options: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("params", "rule_params", "roles", "options"):
            object.__setattr__(self, name, _frozen(getattr(self, name)))
        object.__setattr__(
            self, "role_params", _frozen({k: _frozen(v) for k, v in self.role_params.items()})
        )

    @property
    def name(self) -> str:
        """``family`` or ``family[setting]``: the method's label in reports."""
        return f"{self.family}[{self.setting}]" if self.setting else self.family

    def requirements(self) -> dict[str, str]:
        """role -> registered name this method needs (to check availability)."""
        req = dict(self.roles)
        req["rule"] = self.rule
        if self.predictor:
            req["predictor"] = self.predictor
        return req

    def run_kwargs(self, predictor: str = "constant_velocity") -> dict[str, Any]:
        """Keyword arguments of :func:`~conformal_control.runs.episode.run_episode` (SI units)."""
        kw: dict[str, Any] = {
            "predictor": self.predictor or predictor,
            "params": dict(self.params),
            "units": "si",
            "learn": self.learn,
            "rule": self.rule,
            "rule_params": dict(self.rule_params),
            **self.options,
        }
        for role, name in self.roles.items():
            # "decision_family": a method written by 0.2 (a stored bench.json)
            key = "family" if role == "decision_family" else role
            kw[key] = name
            if role != "fallback" and self.role_params.get(role):
                kw[f"{key}_params"] = dict(self.role_params[role])
        return kw

    def run_spec(self, predictor: str = "constant_velocity") -> RunSpec:
        """The method as a :class:`~conformal_control.core.spec.RunSpec` (SI units), with the
        benchmark's ``predictor`` unless the method names its own."""
        return RunSpec.from_settings(**self.run_kwargs(predictor))

    def as_dict(self) -> dict[str, Any]:
        """Plain description (for ``bench methods`` and the results table)."""
        return {
            "method": self.name,
            "family": self.family,
            "setting": self.setting,
            "description": self.description,
            "learn": self.learn,
            "predictor": self.predictor,
            "params": dict(self.params),
            "rule": self.rule,
            "rule_params": dict(self.rule_params),
            "roles": dict(self.roles),
            "role_params": {k: dict(v) for k, v in self.role_params.items()},
            **({"options": dict(self.options)} if self.options else {}),
        }


# --------------------------------------------------------------------------------------
# families, declared as data
ETA = 1.0 / FRAME  # the paper's eta = 1 per frame


def _frozen_map(d: Mapping[str, Any] | None) -> Mapping[str, Any]:
    return MappingProxyType({k: v for k, v in (d or {}).items()})


@dataclass(frozen=True)
class Family:
    """A method family declared as data: what it runs, and where its one setting goes.

    A new benchmark method is one :class:`Family` entry (in :data:`FAMILIES`, or
    :func:`register_family` from a plugin): its roles by registered name, its parameters,
    and the parameter its setting fills. ``bench run`` runs one :class:`Method` per setting.

    Attributes
    ----------
    name : str
        The family's name (``bench run --methods``).
    description : str
        One line for ``bench methods`` and the reports.
    setting : str or None
        Where a setting goes: ``"params.<key>"`` (a run parameter in SI, e.g.
        ``params.epsilon``), ``"rule_params.<key>"`` or ``"role_params.<role>.<key>"``;
        None for a family without a setting.
    label : str
        How a setting is shown in the method's name (``"eps={:g}"``); a family without a
        setting may still carry a fixed label.
    meaning : str
        What the setting is, with its unit (``bench methods``).
    settings : tuple
        The settings ``bench run`` runs when no tuned value is given.
    tune : tuple
        The grid ``bench tune`` searches (empty: the family is not tuned).
    reference : bool
        ``bench run`` with tuned values keeps the whole ``tune`` grid (the family's
        setting re-tuned per shift on the reported split is then a labelled reference).
    learn, predictor, params, rule, rule_params, roles, role_params, options
        As in :class:`Method`.
    """

    name: str
    description: str
    setting: str | None = None
    label: str = ""
    meaning: str = "-"
    settings: tuple[Any, ...] = (None,)
    tune: tuple[Any, ...] = ()
    reference: bool = False
    learn: bool = True
    predictor: str | None = None
    params: Mapping[str, Any] = field(default_factory=dict)
    rule: str = "fixed_eta"
    rule_params: Mapping[str, Any] = field(default_factory=dict)
    roles: Mapping[str, str] = field(default_factory=dict)
    role_params: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    options: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("params", "rule_params", "roles", "options"):
            object.__setattr__(self, name, _frozen_map(getattr(self, name)))
        object.__setattr__(
            self, "role_params", _frozen_map({k: _frozen(v) for k, v in self.role_params.items()})
        )
        if self.setting is not None:
            head = self.setting.split(".")[0]
            parts = len(self.setting.split("."))
            if head not in ("params", "rule_params", "role_params") or parts != (
                3 if head == "role_params" else 2
            ):
                raise ValueError(
                    f"family {self.name!r}: setting must be params.<key>, rule_params.<key> or "
                    f"role_params.<role>.<key>, got {self.setting!r}"
                )

    def method(self, value: Any = None) -> Method:
        """The member of the family with this setting."""
        params = dict(self.params)
        rule_params = dict(self.rule_params)
        role_params = {k: dict(v) for k, v in self.role_params.items()}
        if self.setting is not None:
            if value is None:
                raise ValueError(f"family {self.name!r} needs a setting ({self.meaning})")
            where, *path = self.setting.split(".")
            if where == "params":
                params[path[0]] = value
            elif where == "rule_params":
                rule_params[path[0]] = value
            else:
                role_params.setdefault(path[0], {})[path[1]] = value
        label = self.label.format(value) if self.label else ""
        return Method(
            self.name,
            label,
            self.description,
            learn=self.learn,
            predictor=self.predictor,
            params=params,
            rule=self.rule,
            rule_params=rule_params,
            roles=self.roles,
            role_params=role_params,
            options=self.options,
        )

    def members(self, grid: Iterable[Any] | None = None) -> list[Method]:
        """One method per setting of ``grid`` (default: :attr:`settings`)."""
        return [self.method(v) for v in (self.settings if grid is None else grid)]


#: The MPC families' search on the crossing suites: 500 sampled sequences of 12 steps of
#: 0.4 s, a plan every video frame (4 control instants), the least violating plan when none
#: is safe.
MPC_SEARCH: dict[str, Any] = {
    "sampling__n_samples": 500,
    "sampling__horizon": 12,
    "sampling__dt_plan": 0.4,
    "sampling__replan_every": 4,
    "fallback": "least_violation",
}

#: The DtACI experts' learning rates on the crossing suites (1/s).
DTACI_GAMMAS = (0.1 * ETA, 0.3 * ETA, ETA, 3 * ETA)
#: The floor of every pedestrian's lambda in the per-pedestrian families (1/s): chosen on
#: the dev split (docs/benchmark.md: per-agent floors -25 to -40/s under the nominal,
#: delayed and noisy predictors), above the feasibility floor -a h_max = -50/s where a far
#: pedestrian's row alone makes the step infeasible.
AGENT_FLOOR = -30.0
#: The per-pedestrian families carry a derived lambda_safe (Theorem 2 per agent, its
#: premise checked at every interval): ``c tan(pi epsilon) - G`` with G the CBF gap bound
#: of :func:`conformal_control.families.cbf.safe_lambda.gap_bound` (-125.8/s at
#: epsilon = -0.05 on the crossing suites).
AGENT_SAFE: Mapping[str, Any] = MappingProxyType({"lambda_safe": "auto"})
#: ``conformal_agent_floorstep``: how far a pedestrian's own floor steps down (1/s) at an
#: update whose lambda sat at it while the pedestrian was still missed, and the lowest it
#: goes (1/s); chosen on the dev split under the 0.5 s delay (docs/benchmark.md, issue 31:
#: the per-pedestrian lambda sits at the -30/s floor at 97 % of biwi_eth's collision frames).
AGENT_FLOOR_STEP = 10.0
AGENT_FLOOR_LIMIT = -60.0

_DECLARED: tuple[Family, ...] = (
    Family("nolearn", "lambda = 0, no learning (pred/noLearn)", learn=False),
    Family(
        "fixed",
        "fixed lambda (a fixed-margin CBF), no learning",
        setting="params.lambda_init",
        label="lambda={:g}/s",
        meaning="lambda (1/s)",
        settings=(-15.0, -30.0, -60.0),
        tune=(-5.0, -10.0, -20.0, -30.0, -45.0),
        reference=True,
        learn=False,
    ),
    Family(
        "conformal",
        "the paper's fixed-eta rule on the CBF gap loss",
        setting="params.epsilon",
        label="eps={:g}",
        meaning="epsilon",
        settings=(-0.1, -0.05, 0.0),
        tune=(-0.2, -0.15, -0.1, -0.05, 0.0),
        params={"eta": ETA},
    ),
    Family(
        "conformal_pid",
        "conformal PID control on the gap loss (P = fixed eta, saturated integrator)",
        setting="params.epsilon",
        label="eps={:g}",
        meaning="epsilon",
        settings=(-0.1,),
        tune=(-0.2, -0.1, -0.05),
        params={"eta": ETA},
        rule="pid",
        rule_params={"K_I": ETA / 2, "C_sat": 1.0},
    ),
    Family(
        "conformal_dtaci",
        "DtACI experts (several learning rates) on the gap loss",
        setting="params.epsilon",
        label="eps={:g}",
        meaning="epsilon",
        settings=(-0.1,),
        tune=(-0.2, -0.1, -0.05),
        rule="dtaci",
        rule_params={"gammas": DTACI_GAMMAS, "sigma": 0.01},
    ),
    Family(
        "conformal_agent",
        "a lambda per pedestrian (its row's slack), each its own fixed-eta rule on its own "
        "gap loss, floored at -30/s",
        setting="params.epsilon",
        label="eps={:g}",
        meaning="epsilon (each pedestrian's target)",
        settings=(-0.05,),
        tune=(-0.2, -0.15, -0.1, -0.05, 0.0),
        params={"eta": ETA, "lambda_per": "agent", "lambda_min": AGENT_FLOOR},
        options=AGENT_SAFE,
    ),
    Family(
        "conformal_agent_dtaci",
        "a lambda per pedestrian, each its own DtACI experts on its own gap loss, floored at -30/s",
        setting="params.epsilon",
        label="eps={:g}",
        meaning="epsilon (each pedestrian's target)",
        settings=(-0.05,),
        tune=(-0.2, -0.1, -0.05, 0.0),
        params={"lambda_per": "agent", "lambda_min": AGENT_FLOOR},
        rule="dtaci",
        rule_params={"gammas": DTACI_GAMMAS, "sigma": 0.01},
        options=AGENT_SAFE,
    ),
    Family(
        "conformal_agent_shortfall",
        "a lambda per pedestrian, each its own DtACI experts on its own shortfall loss (a big "
        "miss moves lambda by more than one step), floored at -30/s",
        setting="params.epsilon",
        label="eps={:g}",
        meaning="epsilon (each pedestrian's target)",
        settings=(-0.05,),
        tune=(-0.2, -0.1, -0.05, 0.0),
        params={"lambda_per": "agent", "lambda_min": AGENT_FLOOR},
        rule="dtaci",
        rule_params={"gammas": DTACI_GAMMAS, "sigma": 0.01},
        roles={"loss": "cbf_shortfall"},
        options=AGENT_SAFE,
    ),
    Family(
        "conformal_agent_floorstep",
        "a lambda per pedestrian, each its own DtACI experts on its own gap loss, floored at "
        f"-30/s; a pedestrian still missed at its floor gets its own floor {AGENT_FLOOR_STEP:g}/s "
        f"lower (down to {AGENT_FLOOR_LIMIT:g}/s)",
        setting="params.epsilon",
        label="eps={:g}",
        meaning="epsilon (each pedestrian's target)",
        settings=(-0.05,),
        tune=(
            -0.05,
        ),  # epsilon: the per-pedestrian DtACI's (dev); the step and limit chosen on dev
        params={
            "lambda_per": "agent",
            "lambda_min": AGENT_FLOOR,
            "lambda_floor_step": AGENT_FLOOR_STEP,
            "lambda_floor_limit": AGENT_FLOOR_LIMIT,
        },
        rule="dtaci",
        rule_params={"gammas": DTACI_GAMMAS, "sigma": 0.01},
        options=AGENT_SAFE,
    ),
    Family(
        "conformal_dtaci_floor",
        "DtACI experts on the gap loss (eps = -0.05) with a lambda floor",
        setting="params.lambda_min",
        label="floor={:g}/s",
        meaning="lambda floor (1/s)",
        settings=(-40.0,),
        tune=(-20.0, -30.0, -40.0, -50.0),
        params={"epsilon": -0.05},
        rule="dtaci",
        rule_params={"gammas": DTACI_GAMMAS, "sigma": 0.01},
    ),
    Family(
        "conformal_aci",
        "ACI's rule on the collision loss: target collision rate per interval",
        setting="rule_params.alpha",
        label="alpha={:g}",
        meaning="alpha (collision rate per interval)",
        settings=(0.05,),
        tune=(0.01, 0.05),
        params={"epsilon": 0.0},
        rule="aci",
        rule_params={"gamma": ETA, "lambda_init": 0.0},
        roles={"loss": "collision"},
    ),
    Family(
        "oracle",
        "the true future as prediction, lambda = 0 (gt/noLearn)",
        learn=False,
        predictor="oracle",
    ),
    Family(
        "inflated",
        "robust CBF: d_c inflated by a fixed margin in the barrier, lambda = 0",
        setting="params.barrier_margin",
        label="margin={:g}m",
        meaning="margin (m)",
        settings=(0.25, 0.5),
        tune=(0.1, 0.25, 0.5),
        learn=False,
    ),
    Family(
        "fallback:brake",
        "the paper's rule (eps = -0.1) with the 'brake' fallback",
        label="eps=-0.1",
        params={"epsilon": -0.1, "eta": ETA},
        roles={"fallback": "brake"},
    ),
    Family(
        "fallback:relax",
        "the paper's rule (eps = -0.1) with the 'relax' fallback",
        label="eps=-0.1",
        params={"epsilon": -0.1, "eta": ETA},
        roles={"fallback": "relax"},
    ),
    Family(
        "acp",
        "adaptive conformal prediction regions inflating each agent's radius (ACI)",
        setting="rule_params.alpha",
        label="alpha={:g}",
        meaning="alpha (miscoverage)",
        settings=(0.1,),
        tune=(0.05, 0.1, 0.2),
        rule="aci",
        rule_params={"gamma": 0.005},
        roles={"family": "acp", "loss": "acp_miscoverage"},
    ),
    Family(
        "mpc",
        "sampling MPC, a fixed safe distance d_c + margin to the predictions, no learning",
        setting="role_params.family.margin",
        label="margin={:g}m",
        meaning="margin (m)",
        settings=(0.0, 0.25, 0.5),
        tune=(0.0, 0.1, 0.25, 0.5, 1.0),
        reference=True,
        learn=False,
        roles={"family": "mpc"},
        role_params={"family": MPC_SEARCH},
    ),
    Family(
        "cc_mpc",
        "conformal controller (CDT): sampling MPC, safe distance d_c - lambda, fixed-eta "
        "rule on the distance shortfall below d_c + 1 m",
        setting="params.epsilon",
        label="eps={:g}",
        meaning="epsilon (distance shortfall)",
        settings=(0.1,),
        tune=(0.05, 0.1, 0.2),
        params={"eta": 0.2, "lambda_min": -1.0, "lambda_max": 1.0},
        roles={"family": "mpc"},
        role_params={"family": MPC_SEARCH},
    ),
    Family(
        "cc_mpc_margin",
        "conformal controller (CDT) on the forecast's clearance error: sampling MPC, safe "
        "distance d_c - lambda, fixed-eta rule on the margin miscoverage (lambda follows the "
        "predictor's error near pedestrians)",
        setting="params.epsilon",
        label="eps={:g}",
        meaning="epsilon (rate of intervals whose clearance error exceeds the margin)",
        settings=(0.1,),
        tune=(0.05, 0.1, 0.2),
        params={"eta": 0.1, "lambda_min": -1.0, "lambda_max": 1.0},
        roles={"family": "mpc", "loss": "margin_miscoverage"},
        role_params={"family": MPC_SEARCH},
    ),
    Family(
        "cc_mpc_margin_agent",
        "cc_mpc_margin with a lambda per pedestrian: pedestrian j's safe distance d_c - "
        "lambda_j, each its own fixed-eta rule on its own clearance error",
        setting="params.epsilon",
        label="eps={:g}",
        meaning="epsilon (each pedestrian's rate of intervals whose clearance error exceeds "
        "its margin)",
        settings=(0.1,),
        tune=(0.05, 0.1, 0.2),
        params={"eta": 0.1, "lambda_min": -1.0, "lambda_max": 1.0, "lambda_per": "agent"},
        roles={"family": "mpc", "loss": "margin_miscoverage_agent"},
        role_params={"family": MPC_SEARCH},
    ),
    Family(
        "cc_mpc_margin_agent_floor",
        "cc_mpc_margin_agent with a floor on each lambda: the rule may add at most 0.2 m of "
        "safe distance to a pedestrian (floor chosen on dev under delay-0.5s)",
        setting="params.lambda_min",
        label="floor={:g}m",
        meaning="lambda floor (m): the most safe distance the rule may add to a pedestrian",
        settings=(-0.2,),
        tune=(-0.1, -0.2, -0.3, -0.5),
        # epsilon: the MPC family's default, 0.1 (cc_mpc_margin_agent's dev-tuned value)
        params={"eta": 0.1, "lambda_min": -0.2, "lambda_max": 1.0, "lambda_per": "agent"},
        roles={"family": "mpc", "loss": "margin_miscoverage_agent"},
        role_params={"family": MPC_SEARCH},
    ),
    Family(
        "cc_mpc_margin_agent_interval",
        "cc_mpc_margin_agent's per-pedestrian distances (each its own lambda, floored) over "
        "the plan steps one interval covers, the fixed d_c + margin beyond "
        "(interval_margin_mpc; floor chosen on dev under delay-0.5s)",
        setting="params.lambda_min",
        label="floor={:g}m",
        meaning="lambda floor (m): the most safe distance the rule may add to a pedestrian",
        settings=(-0.3,),
        tune=(-0.2, -0.3, -0.5, -1.0),
        params={"eta": 0.1, "lambda_min": -0.3, "lambda_max": 1.0, "lambda_per": "agent"},
        roles={"family": "interval_margin_mpc", "loss": "margin_miscoverage_agent"},
        role_params={"family": MPC_SEARCH},
    ),
    Family(
        "oracle_mpc",
        "sampling MPC planning with the true future (oracle predictor), margin 0, no "
        "learning: what perfect prediction gives the MPC",
        learn=False,
        predictor="oracle",
        roles={"family": "mpc"},
        role_params={"family": {**MPC_SEARCH, "margin": 0.0}},
    ),
    Family(
        "acp_mpc",
        "sampling MPC avoiding ACP regions per plan step (ACI on their miscoverage)",
        setting="rule_params.alpha",
        label="alpha={:g}",
        meaning="alpha (miscoverage)",
        settings=(0.1,),
        tune=(0.05, 0.1, 0.2),
        rule="aci",
        rule_params={"gamma": 0.02},
        roles={"family": "acp_mpc"},
        role_params={"family": {**MPC_SEARCH, "max_inflation": 1.0}},
    ),
    Family(
        "fcp_mpc",
        "sampling MPC against conformalized distance fields (FCP-MPC, hard), calibrated "
        "online from the episode's past, with the published adaptation of the envelope",
        setting="params.epsilon",
        label="eps={:g}",
        meaning="epsilon (rate of fields exceeding the envelope)",
        settings=(0.1,),
        tune=(0.05, 0.1, 0.2),
        params={"eta": 0.05, "lambda_init": 0.0, "lambda_min": -4.0, "lambda_max": 0.8},
        roles={"family": "fcp_mpc", "loss": "field_miscoverage"},
        role_params={
            "family": {
                **MPC_SEARCH,
                "continuous": True,
                "calibration__grid_size": 64,
                "calibration__min_pairs": 12,
                "calibration__refit_every": 10,
            }
        },
    ),
    Family(
        "ecp_mpc",
        "sampling MPC avoiding egocentric conformal regions (ACI on their miscoverage)",
        setting="rule_params.alpha",
        label="alpha={:g}",
        meaning="alpha (miscoverage)",
        settings=(0.1,),
        tune=(0.05, 0.1, 0.2),
        rule="aci",
        rule_params={"gamma": 0.02},
        roles={"family": "ecp_mpc"},
        role_params={"family": {**MPC_SEARCH, "max_inflation": 1.0}},
    ),
)

#: name -> family: every benchmark method family (``conformal-control bench methods``).
FAMILIES: dict[str, Family] = {f.name: f for f in _DECLARED}
#: The same table under its former name.
METHOD_FAMILIES = FAMILIES

#: The method families ``bench run`` runs by default: the baseline, the fixed margin (its
#: whole tuning grid, for the re-tuned reference), the conformal rule, ACP, the robust CBF,
#: and the recommended adaptive method, DtACI with a lambda floor (on crossings-v2's test
#: split the best of the dev-tuned adaptive methods under the 0.5 s delay, equal to
#: ``conformal`` under the nominal, frozen and learned predictors, mixed under the others:
#: docs/benchmark.md, "lambda per pedestrian").
DEFAULT_METHODS = ("nolearn", "fixed", "conformal", "acp", "inflated", "conformal_dtaci_floor")


def register_family(family: Family, *, replace: bool = False) -> Family:
    """Add a method family to :data:`FAMILIES` (a plugin's methods: one entry each).

    Raises
    ------
    ValueError
        If the name is taken (unless ``replace``).
    """
    if family.name in FAMILIES and not replace:
        raise ValueError(f"a method family named {family.name!r} exists already")
    FAMILIES[family.name] = family
    return family


def expand_methods(
    families: Iterable[str], grids: Mapping[str, Iterable[Any]] | None = None
) -> list[Method]:
    """Every method of ``families`` over their settings (``grids`` overrides a family's).

    Raises
    ------
    ValueError
        For an unknown family (the message lists the known ones).
    """
    out: list[Method] = []
    grids = dict(grids or {})
    for fam in families:
        if fam not in FAMILIES:
            import difflib

            close = difflib.get_close_matches(fam, FAMILIES, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ValueError(f"unknown method {fam!r}{hint} known: {', '.join(FAMILIES)}")
        out.extend(FAMILIES[fam].members(grids.get(fam)))
    return out


def available(method: Method) -> str | None:
    """None if every plugin the method needs is registered and loadable, else why not."""
    from ...core import registry

    for role, name in method.requirements().items():
        try:
            registry.get(role, name)
        except (registry.UnknownPluginError, registry.PluginUnavailableError) as exc:
            return str(exc)
    return None
