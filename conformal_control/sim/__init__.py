"""Episode simulation: replay environment, parameters, runner, run directories."""

from .build import Flagship, build_flagship, build_rule
from .config import PARAMETERS, ResolvedParams, parse_value, resolve_params
from .environment import ReplayEnvironment
from .episode import EpisodeResult, run_episode
from .metrics import EpisodeMetrics

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
