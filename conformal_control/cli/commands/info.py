"""Informational commands: ``scenes``, ``params`` (``plugins`` lives in ``plugins.py``)."""

from __future__ import annotations

import argparse
from typing import Any

from . import add_data_root, command


@command("scenes", "list the registered scenes")
def _scenes_args(p: argparse.ArgumentParser) -> None:
    pass


@_scenes_args.handler
def _scenes(args: argparse.Namespace) -> int:
    from ...data.scenes import PAPER_SCENES

    print("crossing        built-in synthetic crossing flows (no data needed; SI units)")
    for s in PAPER_SCENES.values():
        goals = " -> ".join(f"({g[0]}, {g[1]})" for g in s.goals)
        print(
            f"{s.name:<15} SDD {s.sdd_scene}/video{s.video} ({s.source}); start {s.start} -> "
            f"{goals}; frame {s.start_frame}; v_max {s.v_max} m/s {s.note}"
        )
    from ...data.ethucy import ETHUCY_RECORDINGS

    print(
        "sdd:<scene>/video<N>  any SDD video with raw annotations (--start/--goal: fractions "
        "of its image, or metres 3.2m,1.0m)"
    )
    print(
        f"ethucy:<recording>    an ETH/UCY recording ({', '.join(ETHUCY_RECORDINGS)}; the "
        "splits eth, hotel, zara1, zara2 name theirs); default task: across its walkable box "
        "(--start/--goal: fractions of the box, or metres)"
    )
    return 0


@command("params", "list the controller parameters, their units and a scene's defaults")
def _params_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--scene",
        default=None,
        help="show this scene's units and resolved defaults (e.g. crossing, nexus_4)",
    )
    add_data_root(p, " for SDD scenes")


_DIMENSION_WORDS = {
    (1, 0): "length",
    (2, 0): "length^2",
    (0, 1): "time",
    (0, -1): "1/time",
}


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


@_params_args.handler
def _params(args: argparse.Namespace) -> int:
    from ...data.units import PARAM_DIMENSIONS
    from ...runs.params import PARAMETERS, UNIT_SUFFIXES

    if not args.scene:
        print(
            "Dimensional parameters are typed in the scene's units (SDD scenes: px and frames, "
            "the paper's; the built-in scene: m and s) or with a unit suffix; "
            "`conformal-control params --scene NAME` shows a scene's units and defaults."
        )
        print(f"{'name':<15} {'dimension':<10} {'suffixes':<29} {'default':<14} meaning")
        for name, (default, doc) in PARAMETERS.items():
            dim = PARAM_DIMENSIONS.get(name)
            word = _DIMENSION_WORDS.get(dim, "-") if dim else "-"
            suffixes = ", ".join(UNIT_SUFFIXES.get(dim, ())) if dim else ""
            shown = "scene" if default is None else _fmt(default)
            print(f"{name:<15} {word:<10} {suffixes:<29} {shown:<14} {doc}")
        return 0

    from ...data import load_scene
    from ...runs.params import resolve_params

    scene = load_scene(args.scene, args.data_root)
    resolved = resolve_params(scene, {})
    used, si = resolved.scene_units, resolved.si
    u = scene.units
    if u.length_name == "m" and u.time_name == "s":
        units = "m and s (SI)"
    else:
        units = (
            f"{u.length_name} and {u.time_name}s: 1 {u.length_name} = {u.length:.6g} m, "
            f"1 {u.time_name} = {u.time:.6g} s ({scene.fps:g} fps)"
        )
    print(
        f"scene {scene.name}: parameters are typed in {units}; a unit suffix (rho0=18m, "
        "tau=0.4s, eta=30/s) converts"
    )
    print(f"{'name':<15} {'value':<14} {'unit':<10} {'SI value':<16} meaning")
    si_units = {(1, 0): "m", (2, 0): "m^2", (0, 1): "s", (0, -1): "1/s"}
    for name, (_default, doc) in PARAMETERS.items():
        value = used.get(name)
        dim = PARAM_DIMENSIONS.get(name)
        if dim:
            unit = u.unit_of(name)
            si_text = f"{_fmt(si[name])} {si_units[dim]}" if value is not None else ""
        else:
            unit = {"v_max": "m/s"}.get(name, "m" if name.endswith("radius") else "-")
            si_text = ""
        shown = "derived" if value is None else _fmt(value)
        print(f"{name:<15} {shown:<14} {unit:<10} {si_text:<16} {doc}")
    return 0
