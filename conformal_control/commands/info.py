"""Informational commands: ``scenes``, ``params`` (``plugins`` lives in ``plugins.py``)."""

from __future__ import annotations

import argparse
from typing import Any

from . import command


@command("scenes", "list the registered scenes")
def _scenes_args(p: argparse.ArgumentParser) -> None:
    pass


@_scenes_args.handler
def _scenes(args: argparse.Namespace) -> int:
    from ..data.scenes import PAPER_SCENES

    print("crossing        built-in synthetic crossing flows (no data needed; SI units)")
    for s in PAPER_SCENES.values():
        goals = " -> ".join(f"({g[0]}, {g[1]})" for g in s.goals)
        print(
            f"{s.name:<15} SDD {s.sdd_scene}/video{s.video} ({s.source}); start {s.start} -> "
            f"{goals}; frame {s.start_frame}; v_max {s.v_max} m/s {s.note}"
        )
    print("sdd:<scene>/video<N>  any SDD video with raw annotations (--start/--goal fractions)")
    return 0


@command("params", "list the controller parameters and their units")
def _params_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scene", default=None, help="show the defaults of this scene")
    p.add_argument("--data-root", default=None)


@_params_args.handler
def _params(args: argparse.Namespace) -> int:
    from ..sim.config import PARAMETERS

    defaults: dict[str, Any] = {}
    if args.scene:
        from ..data import load_scene
        from ..sim.config import resolve_params

        scene = load_scene(args.scene, args.data_root)
        defaults = resolve_params(scene, {}).scene_units
    for name, (default, doc) in PARAMETERS.items():
        value = defaults.get(name, default)
        print(f"{name:<15} {value!s:<14} {doc}")
    return 0
