"""Reinforcement-learning environments (gymnasium, PettingZoo) around the conformal CBF.

Needs the ``rl`` extra (``pip install -e ".[rl]"``: gymnasium and PettingZoo).

* ``ConformalCrowd-v0`` (:class:`ConformalCrowdEnv`, registered with gymnasium when this
  package is imported): one robot crossing a replayed or reactive crowd, the action its
  velocity command. In a fresh interpreter, ``gymnasium.make(
  "conformal_control.envs:ConformalCrowd-v0")`` imports this package and makes it
  (gymnasium 1.x loads no plugin entry points: the id with its module is the way a
  program that takes environment ids as strings finds it);
* :class:`ConformalShield`: a wrapper that filters any policy's actions through the
  conformal CBF with its own predictor and online lambda, reporting its interventions
  (a constraint shaped the action) apart from speed clips (only ``v_max`` did);
* :class:`ConformalCrowdParallel`: the multi-robot case as a PettingZoo parallel
  environment (agents = robots), and :class:`ReciprocalShield`, its shield: every robot's
  action filtered by its own conformal CBF, the robots' rows shared
  (:mod:`conformal_control.families.cbf.reciprocal`).

Observation, action, reward and ``info`` are described in :mod:`conformal_control.envs.core`.
"""

from __future__ import annotations

try:
    import gymnasium
except ImportError as exc:  # pragma: no cover - exercised without the extra only
    raise ImportError(
        "conformal_control.envs needs gymnasium and PettingZoo: pip install -e '.[rl]'"
    ) from exc

from .crowd import ConformalCrowdEnv
from .shield import ConformalShield

__all__ = [
    "ENV_ID",
    "ConformalCrowdEnv",
    "ConformalCrowdParallel",
    "ConformalShield",
    "ReciprocalShield",
]

#: The gymnasium id of :class:`ConformalCrowdEnv`.
ENV_ID = "ConformalCrowd-v0"

if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="conformal_control.envs.crowd:ConformalCrowdEnv")


def __getattr__(name: str) -> object:
    # PettingZoo is imported only when the parallel environment is asked for
    if name == "ConformalCrowdParallel":
        from .parallel import ConformalCrowdParallel

        return ConformalCrowdParallel
    if name == "ReciprocalShield":
        from .parallel import ReciprocalShield

        return ReciprocalShield
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
