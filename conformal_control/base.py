"""Abstract base classes: one small ABC per role.

Every plugin of the toolkit derives from exactly one of these classes. They follow the
scikit-learn / river habits: constructor arguments are stored unchanged as attributes of
the same name (so :meth:`Plugin.get_params` can report them and a run can write its full
configuration), no work happens in ``__init__``, and state that is learned or accumulated
while running lives in attributes set by ``reset``.

Roles and what they compute
---------------------------
``Predictor``            histories of sensed agents  -> predicted trajectories (batched)
``Barrier``              ego position, agent positions -> h, dh/dx_ego, dh/dx_agent
``SafetyFilter``         nominal decision + conformal constraints + lambda -> safe decision
``Loss``                 interval record + ground truth + lambda -> scalar loss
``UpdateRule``           loss -> next lambda
``Dynamics``             state, command, dt -> next state
``ReferenceController``  state, t -> nominal (reference) decision
``Environment``          the world the decisions act on (sensor, plant, ground truth)
``DecisionFamily``       the family D^lambda of decision functions, ordered by conservativeness

Sign convention (all of the toolkit): a *smaller* lambda is *more conservative*.
"""

from __future__ import annotations

import inspect
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

__all__ = [
    "Barrier",
    "DecisionFamily",
    "Dynamics",
    "Environment",
    "FilterResult",
    "Forecast",
    "Loss",
    "Plugin",
    "PredictionQuery",
    "Predictor",
    "ReferenceController",
    "SafetyFilter",
    "UpdateRule",
]


class Plugin:
    """Mixin giving every plugin ``get_params`` / ``describe`` like scikit-learn estimators.

    Subclasses store each ``__init__`` argument under an attribute of the same name.
    """

    #: One-line description shown by ``conformal-control plugins``. Defaults to the first
    #: line of the class docstring.
    description: ClassVar[str | None] = None

    @classmethod
    def _param_names(cls) -> list[str]:
        init = cls.__init__
        if init is object.__init__:
            return []
        sig = inspect.signature(init)
        return [
            p.name
            for p in sig.parameters.values()
            if p.name != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)
        ]

    def get_params(self) -> dict[str, Any]:
        """Return the constructor parameters of this plugin (name -> value)."""
        return {name: getattr(self, name) for name in self._param_names() if hasattr(self, name)}

    @classmethod
    def summary(cls) -> str:
        """One-line description of the plugin."""
        if cls.description:
            return cls.description
        doc = inspect.getdoc(cls) or ""
        return doc.strip().splitlines()[0] if doc.strip() else cls.__name__

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"


# --------------------------------------------------------------------------------------
# Data passed between roles
# --------------------------------------------------------------------------------------
@dataclass
class PredictionQuery:
    """What the sensor hands the predictor at a sampling time (batched over agents).

    Attributes
    ----------
    ids : ndarray of shape (N,)
        Identifiers of the sensed agents.
    history : ndarray of shape (N, T, 2)
        Past positions in metres, one row per sample at spacing ``dt``; the last sample
        (``history[:, -1]``) is the position at the sampling time and is always finite.
        Samples where an agent was not observed are NaN (short histories are NaN-padded
        at the front; gaps are NaN in the middle).
    dt : float
        Sample spacing in seconds (1 / the scene's frame rate).
    horizon : int
        Number of future samples requested (positions at ``dt, 2 dt, ..., horizon dt``).
    t : float
        Time of the sampling instant in seconds since the episode started.
    frame : int
        Video frame number of the sampling instant (used as a cache key by expensive
        predictors).
    scene : str
        Name of the scene (cache key).
    ground_truth : ndarray of shape (N, horizon, 2) or None
        The true future. Only filled in for predictors whose class sets
        ``requires_ground_truth = True`` (the oracle baseline); ``None`` otherwise.
    """

    ids: np.ndarray
    history: np.ndarray
    dt: float
    horizon: int
    t: float = 0.0
    frame: int = 0
    scene: str = ""
    ground_truth: np.ndarray | None = None

    @property
    def n_agents(self) -> int:
        return int(self.history.shape[0])

    @property
    def current(self) -> np.ndarray:
        """Positions at the sampling time, shape (N, 2)."""
        return self.history[:, -1, :]


@dataclass
class Forecast:
    """Output of a predictor.

    Attributes
    ----------
    positions : ndarray of shape (N, H, 2)
        Predicted positions in metres at ``dt, ..., H dt`` after the sampling time.
    covariance : ndarray of shape (N, H, 2, 2) or None
        Optional predictive covariance (m^2), for predictors that have one.
    info : dict
        Free-form counters (e.g. ``{"n_fallback": 2}``) merged into run metrics.
    """

    positions: np.ndarray
    covariance: np.ndarray | None = None
    info: dict[str, Any] = field(default_factory=dict)


@dataclass
class FilterResult:
    """Output of a safety filter for one decision.

    Attributes
    ----------
    decision : ndarray
        The (safe) decision actually applied.
    status : str
        ``"optimal"`` (constraints met at the requested lambda), ``"unconstrained"``
        (no constraint was active or present), or ``"fallback"``.
    lambda_applied : float
        The lambda the returned decision satisfies the constraints with. Equal to the
        requested lambda unless the fallback raised it; ``nan`` for a fallback that does
        not satisfy the constraints at any lambda (``"brake"``, ``"hold"``).
    fallback : str or None
        Name of the fallback used, if any.
    """

    decision: np.ndarray
    status: str
    lambda_applied: float
    fallback: str | None = None


# --------------------------------------------------------------------------------------
# Roles
# --------------------------------------------------------------------------------------
class Predictor(Plugin, ABC):
    """Black-box trajectory predictor, batched over the sensed agents.

    Subclasses implement :meth:`predict`. A predictor must not modify the query, must
    return finite positions for every agent whose last history sample is finite (or NaN
    that the controller then replaces by a documented, counted fallback), and must be
    deterministic for a given ``random_state`` if it has one.
    """

    #: Set to True by predictors that cheat by reading ``query.ground_truth``.
    requires_ground_truth: ClassVar[bool] = False

    def reset(self) -> None:
        """Forget any state accumulated during an episode (optional)."""

    @abstractmethod
    def predict(self, query: PredictionQuery) -> Forecast:
        """Predict ``query.horizon`` future positions for each of the ``query.n_agents``."""


class Barrier(Plugin, ABC):
    """Pairwise control barrier function h(x_ego, x_agent) on positions (metres).

    ``h >= 0`` is the safe set. Implementations are vectorised: ``x_ego`` and
    ``x_agent`` broadcast against each other over leading dimensions.
    """

    @abstractmethod
    def evaluate(
        self, x_ego: np.ndarray, x_agent: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return ``(h, dh_dego, dh_dagent)``.

        Parameters
        ----------
        x_ego : ndarray of shape (..., 2)
        x_agent : ndarray of shape (..., 2)

        Returns
        -------
        h : ndarray of shape (...)
        dh_dego : ndarray of shape (..., 2)
            Exact gradient with respect to the ego position.
        dh_dagent : ndarray of shape (..., 2)
            Exact gradient with respect to the agent position.
        """

    def value(self, x_ego: np.ndarray, x_agent: np.ndarray) -> np.ndarray:
        """Barrier value only."""
        return self.evaluate(x_ego, x_agent)[0]

    @property
    def upper_bound(self) -> float | None:
        """Supremum of h (used to compute the feasibility floor), or None if unbounded."""
        return None


class SafetyFilter(Plugin, ABC):
    """Minimally modify a nominal decision so that conformal constraints hold.

    The constraints are ``A @ u + b + lam >= 0`` row-wise (one row per sensed agent).
    """

    @abstractmethod
    def solve(self, nominal: np.ndarray, A: np.ndarray, b: np.ndarray, lam: float) -> FilterResult:
        """Return the decision closest to ``nominal`` satisfying the constraints."""

    def reset(self) -> None:
        """Reset counters (optional)."""


class Loss(Plugin, ABC):
    """Loss of the decisions taken over one interval, once the truth is revealed.

    ``bounds`` declares the range the loss takes values in (needed by the guarantees).
    Returning ``None`` means "no loss for this interval" (e.g. nothing was sensed); the
    loop then does not update lambda.
    """

    bounds: ClassVar[tuple[float, float]] = (-0.5, 0.5)

    @abstractmethod
    def __call__(self, record: Any, truth: Any, lam: float) -> float | None:
        """Loss l_k of interval k evaluated with the conformal variable ``lam``."""

    def diagnostics(self, record: Any, truth: Any, lam: float) -> dict[str, float]:
        """Extra per-interval figures to log beside the loss (optional)."""
        return {}


class UpdateRule(Plugin, ABC):
    """Online update of the conformal variable lambda.

    Convention: ``update`` receives the loss l_k of the interval that just ended and
    returns lambda_{k+1}; a loss above target must not increase lambda (smaller lambda is
    more conservative).
    """

    #: Target average loss of the rule (epsilon).
    epsilon: float

    #: Which guarantee the rule keeps, read by the monitor: ``"identity"`` (fixed step:
    #: exact identity + Theorem-2 bound), ``"step_identity"`` (variable step: weighted
    #: identity + long-run bound), ``"long_run"`` (a bound on |mean loss - epsilon|) or
    #: ``"none"``. See :mod:`conformal_control.update_rules`.
    guarantee: ClassVar[str] = "none"

    #: Rules that want the interval's loss as a function of lambda (counterfactual losses,
    #: e.g. DtACI's experts) set this; the loop then calls :meth:`set_loss_function`
    #: before each :meth:`update`.
    uses_loss_function: ClassVar[bool] = False

    #: Constructor parameters expressed in the units of lambda (scene-unit conversion).
    lambda_params: ClassVar[tuple[str, ...]] = ()

    def set_loss_function(self, fn: Any) -> None:
        """Receive ``fn(lam) -> loss`` for the next update (ignored by default)."""

    def long_run_bound(self, n: int, lambdas: Any) -> float | None:
        """Bound on |mean loss - epsilon| after ``n`` updates (lambda_1..lambda_{n+1})."""
        return None

    @abstractmethod
    def reset(self) -> float:
        """Reset the rule and return lambda_1."""

    @abstractmethod
    def update(self, loss: float) -> float:
        """Consume l_k and return lambda_{k+1}."""

    @property
    @abstractmethod
    def value(self) -> float:
        """Current lambda."""


class Dynamics(Plugin, ABC):
    """Plant of the ego agent: ``state`` is a flat float array."""

    state_dim: ClassVar[int]

    @abstractmethod
    def step(self, state: np.ndarray, command: np.ndarray, dt: float) -> np.ndarray:
        """State after holding ``command`` for ``dt`` seconds (returns a new array)."""

    def position(self, state: np.ndarray) -> np.ndarray:
        """Position part of the state (metres)."""
        return state[:2]

    def velocity(self, state: np.ndarray) -> np.ndarray:
        """Velocity part of the state (m/s)."""
        return state[2:4]


class ReferenceController(Plugin, ABC):
    """Nominal controller the safety filter minimally modifies."""

    @abstractmethod
    def __call__(self, state: np.ndarray, t: float) -> np.ndarray:
        """Nominal decision at state ``state`` and time ``t``."""

    def reset(self) -> None:
        """Reset internal state (e.g. the current waypoint)."""


class Environment(ABC):
    """The world the conformal loop acts on (gymnasium-like, episodic).

    One *interval* k spans the control instants between sampling times k and k+1.
    """

    @abstractmethod
    def reset(self) -> None:
        """Start a new episode."""

    @property
    @abstractmethod
    def done(self) -> bool:
        """Whether the episode is over (no further interval will be run)."""

    @abstractmethod
    def sense(self, with_ground_truth: bool = False) -> Any:
        """Observation at the sampling time (the predictor's input).

        ``with_ground_truth`` asks the environment to attach the true future, for
        predictors that declare ``requires_ground_truth`` (the oracle baseline).
        """

    @abstractmethod
    def control_instants(self) -> int:
        """Number of control instants in the interval starting now."""

    @abstractmethod
    def state(self) -> Any:
        """The decision input at the current control instant."""

    @abstractmethod
    def apply(self, decision: Any) -> None:
        """Apply a decision for one control step and advance time."""

    @abstractmethod
    def reveal(self) -> Any:
        """Ground truth over the interval that just finished."""


class DecisionFamily(Plugin, ABC):
    """The family {D^lambda} of decision functions, ordered by conservativeness."""

    @abstractmethod
    def begin_interval(self, observation: Any, prediction: Any) -> None:
        """Receive the sensor's observation and the prediction at a sampling time."""

    @abstractmethod
    def decide(self, state: Any, lam: float) -> Any:
        """Decision D^lam(state) at the current control instant."""

    @abstractmethod
    def interval_record(self) -> Any:
        """Everything the loss needs about the decisions of the current interval."""

    def reset(self) -> None:
        """Reset between episodes."""
