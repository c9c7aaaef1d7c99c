"""The flagship wired on a scene: parameters resolved in the scene's units and in SI, every
role built from an instance, a registered name or the paper's default."""

from .build import Flagship, RoleSpec, build_flagship, build_rule
from .params import PARAMETERS, ResolvedParams, parse_value, resolve_params

__all__ = [
    "PARAMETERS",
    "Flagship",
    "ResolvedParams",
    "RoleSpec",
    "build_flagship",
    "build_rule",
    "parse_value",
    "resolve_params",
]
