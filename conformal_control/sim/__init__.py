"""Running episodes: one robot (:func:`run_episode`) or several (:mod:`.multi`).

The pieces live one floor down and are re-exported here as the public front of a run:
wiring is :mod:`conformal_control.flagship`, the backends :mod:`conformal_control.engines`,
the world :mod:`conformal_control.world`, what comes out :mod:`conformal_control.results`.
"""

from ..flagship.build import Flagship, build_flagship, build_rule
from ..flagship.params import PARAMETERS, ResolvedParams, parse_value, resolve_params
from ..results.episode import EpisodeResult
from ..results.metrics import EpisodeMetrics
from ..world.replay import ReplayEnvironment
from .episode import run_episode

__all__ = [
    "PARAMETERS",
    "EpisodeMetrics",
    "EpisodeResult",
    "Flagship",
    "ReplayEnvironment",
    "ResolvedParams",
    "build_flagship",
    "build_rule",
    "parse_value",
    "resolve_params",
    "run_episode",
]
