"""Episode simulation: replay environment, parameters, runner, run directories."""

from .config import PARAMETERS, ResolvedParams, parse_value, resolve_params
from .environment import ReplayEnvironment
from .episode import EpisodeResult, build_components, run_episode

__all__ = [
    "PARAMETERS",
    "EpisodeResult",
    "ReplayEnvironment",
    "ResolvedParams",
    "build_components",
    "parse_value",
    "resolve_params",
    "run_episode",
]
