"""Benchmark methods: named, composable configurations of the flagship.

A :class:`Method` is a family name, a setting, and what it changes in the flagship: run
parameters (SI units: lambda and eta in 1/s, lengths in m), the update rule, and any role
given by registered name (barrier, safety filter, fallback, loss, predictor). Every
method runs through the same public builder (:func:`conformal_control.sim.build_flagship`
via :func:`conformal_control.sim.run_episode`), so a user can reproduce any row of a
leaderboard with ``run_episode(scene, **method.run_kwargs(predictor))``.

The families (``conformal-control bench methods`` lists them with their settings):

``nolearn``        lambda = 0, no learning (the paper's pred/noLearn)
``fixed``          a fixed lambda < 0 (a fixed-margin CBF), no learning
``conformal``      the paper's fixed-eta rule on the gap loss, over an epsilon grid
``conformal_pid``  conformal PID control (Angelopoulos et al. 2023) on the gap loss
``conformal_dtaci`` DtACI experts (Gibbs & Candes 2022) on the gap loss
``conformal_aci``  ACI's rule on the collision loss (target: a collision rate per interval)
``oracle``         the true future as prediction, lambda = 0 (the paper's gt/noLearn)
``inflated``       a robust CBF: d_c inflated by a fixed margin in the barrier, lambda = 0
``fallback:*``     ``conformal`` with another fallback (``brake``, ``relax``)
``acp``            adaptive conformal prediction regions (when registered)
``mpc``            the sampling MPC with a fixed safe distance (margin grid), no learning
``cc_mpc``         the CDT conformal controller: the sampling MPC learning its distance
``acp_mpc``        the sampling MPC avoiding ACP regions per plan step
``ecp_mpc``        the sampling MPC avoiding egocentric conformal regions

The MPC families are not in the default method set (``--methods mpc,cc_mpc,...``).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

__all__ = [
    "DEFAULT_METHODS",
    "FRAME",
    "METHOD_FAMILIES",
    "Method",
    "available",
    "expand_methods",
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

    def __post_init__(self) -> None:
        for name in ("params", "rule_params", "roles"):
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
        req["update_rule"] = self.rule
        if self.predictor:
            req["predictor"] = self.predictor
        return req

    def run_kwargs(self, predictor: str = "constant_velocity") -> dict[str, Any]:
        """Keyword arguments of :func:`~conformal_control.sim.run_episode` (SI units)."""
        kw: dict[str, Any] = {
            "predictor": self.predictor or predictor,
            "params": dict(self.params),
            "units": "si",
            "learn": self.learn,
            "rule": self.rule,
            "rule_params": dict(self.rule_params),
        }
        for role, name in self.roles.items():
            key = "family" if role == "decision_family" else role
            kw[key] = name
            if role != "fallback" and self.role_params.get(role):
                kw[f"{key}_params"] = dict(self.role_params[role])
        return kw

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
        }


# --------------------------------------------------------------------------------------
# families: name -> (settings grid, factory)
ETA = 1.0 / FRAME  # the paper's eta = 1 per frame


def _nolearn(_: Any) -> Method:
    return Method("nolearn", "", "lambda = 0, no learning (pred/noLearn)", learn=False)


def _fixed(lam: float) -> Method:
    return Method(
        "fixed",
        f"lambda={lam:g}/s",
        "fixed lambda (a fixed-margin CBF), no learning",
        learn=False,
        params={"lambda_init": lam},
    )


def _conformal(eps: float) -> Method:
    return Method(
        "conformal",
        f"eps={eps:g}",
        "the paper's fixed-eta rule on the CBF gap loss",
        params={"epsilon": eps, "eta": ETA},
    )


def _pid(eps: float) -> Method:
    return Method(
        "conformal_pid",
        f"eps={eps:g}",
        "conformal PID control on the gap loss (P = fixed eta, saturated integrator)",
        params={"epsilon": eps, "eta": ETA},
        rule="pid",
        rule_params={"K_I": ETA / 2, "C_sat": 1.0},
    )


def _dtaci(eps: float) -> Method:
    return Method(
        "conformal_dtaci",
        f"eps={eps:g}",
        "DtACI experts (several learning rates) on the gap loss",
        params={"epsilon": eps},
        rule="dtaci",
        rule_params={"gammas": (0.1 * ETA, 0.3 * ETA, ETA, 3 * ETA), "sigma": 0.01},
    )


def _aci(alpha: float) -> Method:
    return Method(
        "conformal_aci",
        f"alpha={alpha:g}",
        "ACI's rule on the collision loss: target collision rate per interval",
        params={"epsilon": 0.0},
        rule="aci",
        rule_params={"alpha": alpha, "gamma": ETA, "lambda_init": 0.0},
        roles={"loss": "collision"},
    )


def _oracle(_: Any) -> Method:
    return Method(
        "oracle", "", "the true future as prediction, lambda = 0 (gt/noLearn)", False, "oracle"
    )


def _inflated(margin: float) -> Method:
    return Method(
        "inflated",
        f"margin={margin:g}m",
        "robust CBF: d_c inflated by a fixed margin in the barrier, lambda = 0",
        learn=False,
        params={"barrier_margin": margin},
    )


def _fallback(name: str) -> Method:
    return Method(
        f"fallback:{name}",
        "eps=-0.1",
        f"the paper's rule (eps = -0.1) with the {name!r} fallback",
        params={"epsilon": -0.1, "eta": ETA},
        roles={"fallback": name},
    )


def _acp(alpha: float) -> Method:
    return Method(
        "acp",
        f"alpha={alpha:g}",
        "adaptive conformal prediction regions inflating each agent's radius (ACI)",
        rule="aci",
        rule_params={"alpha": alpha, "gamma": 0.005},
        roles={"decision_family": "acp", "loss": "acp_miscoverage"},
    )


#: The MPC families' search on the crossing suites: 500 sampled sequences of 12 steps of
#: 0.4 s, a plan every video frame (4 control instants), the least violating plan when none
#: is safe.
MPC_SEARCH: dict[str, Any] = {
    "n_samples": 500,
    "horizon": 12,
    "dt_plan": 0.4,
    "replan_every": 4,
    "fallback": "least_violation",
}


def _mpc(margin: float) -> Method:
    return Method(
        "mpc",
        f"margin={margin:g}m",
        "sampling MPC, a fixed safe distance d_c + margin to the predictions, no learning",
        learn=False,
        roles={"decision_family": "mpc"},
        role_params={"decision_family": {**MPC_SEARCH, "margin": margin}},
    )


def _cc_mpc(eps: float) -> Method:
    return Method(
        "cc_mpc",
        f"eps={eps:g}",
        "conformal controller (CDT): sampling MPC, safe distance d_c - lambda, fixed-eta "
        "rule on the distance shortfall below d_c + 1 m",
        params={"epsilon": eps, "eta": 0.2, "lambda_min": -1.0, "lambda_max": 1.0},
        roles={"decision_family": "mpc"},
        role_params={"decision_family": dict(MPC_SEARCH)},
    )


def _acp_mpc(alpha: float) -> Method:
    return Method(
        "acp_mpc",
        f"alpha={alpha:g}",
        "sampling MPC avoiding ACP regions per plan step (ACI on their miscoverage)",
        rule="aci",
        rule_params={"alpha": alpha, "gamma": 0.02},
        roles={"decision_family": "acp_mpc"},
        role_params={"decision_family": {**MPC_SEARCH, "max_inflation": 1.0}},
    )


def _ecp_mpc(alpha: float) -> Method:
    return Method(
        "ecp_mpc",
        f"alpha={alpha:g}",
        "sampling MPC avoiding egocentric conformal regions (ACI on their miscoverage)",
        rule="aci",
        rule_params={"alpha": alpha, "gamma": 0.02},
        roles={"decision_family": "ecp_mpc"},
        role_params={"decision_family": {**MPC_SEARCH, "max_inflation": 1.0}},
    )


#: family -> (default settings, factory, settings meaning)
METHOD_FAMILIES: dict[str, tuple[tuple[Any, ...], Any, str]] = {
    "nolearn": ((None,), _nolearn, "-"),
    "fixed": ((-15.0, -30.0, -60.0), _fixed, "lambda (1/s)"),
    "conformal": ((-0.1, -0.05, 0.0), _conformal, "epsilon"),
    "conformal_pid": ((-0.1,), _pid, "epsilon"),
    "conformal_dtaci": ((-0.1,), _dtaci, "epsilon"),
    "conformal_aci": ((0.05,), _aci, "alpha (collision rate per interval)"),
    "oracle": ((None,), _oracle, "-"),
    "inflated": ((0.25, 0.5), _inflated, "margin (m)"),
    "fallback:brake": ((None,), lambda _: _fallback("brake"), "-"),
    "fallback:relax": ((None,), lambda _: _fallback("relax"), "-"),
    "acp": ((0.1,), _acp, "alpha (miscoverage)"),
    "mpc": ((0.0, 0.25, 0.5), _mpc, "margin (m)"),
    "cc_mpc": ((0.1,), _cc_mpc, "epsilon (distance shortfall)"),
    "acp_mpc": ((0.1,), _acp_mpc, "alpha (miscoverage)"),
    "ecp_mpc": ((0.1,), _ecp_mpc, "alpha (miscoverage)"),
}

#: The default method set of ``bench run``.
DEFAULT_METHODS = (
    "nolearn",
    "fixed",
    "conformal",
    "conformal_pid",
    "conformal_dtaci",
    "conformal_aci",
    "oracle",
    "inflated",
    "fallback:brake",
    "fallback:relax",
    "acp",
)


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
        if fam not in METHOD_FAMILIES:
            import difflib

            close = difflib.get_close_matches(fam, METHOD_FAMILIES, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ValueError(f"unknown method {fam!r}{hint} known: {', '.join(METHOD_FAMILIES)}")
        settings, factory, _ = METHOD_FAMILIES[fam]
        for value in grids.get(fam, settings):
            out.append(factory(value))
    return out


def available(method: Method) -> str | None:
    """None if every plugin the method needs is registered and loadable, else why not."""
    from .. import registry

    for role, name in method.requirements().items():
        try:
            registry.get(role, name)
        except (registry.UnknownPluginError, registry.PluginUnavailableError) as exc:
            return str(exc)
    return None
