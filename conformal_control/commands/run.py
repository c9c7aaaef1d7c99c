"""``conformal-control run``: one episode of the conformal CBF controller."""

from __future__ import annotations

import argparse
import datetime as _dt
import sys
from pathlib import Path
from typing import Any

from . import command, key_values


def _pair(text: str) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected two numbers 'fx,fy', got {text!r}") from None
    return a, b


@command("run", "run the conformal CBF controller on a scene and write a run directory")
def _run_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--scene",
        default="crossing",
        help="crossing (built-in, default), a paper scene (nexus_4, gates_1, ...), "
        "or sdd:<scene>/video<N>",
    )
    p.add_argument(
        "--data-root",
        default=None,
        help="data folder (or its sdd/ subfolder); default $CONFORMAL_CONTROL_DATA",
    )
    p.add_argument("--predictor", default="constant_velocity", help="registered predictor name")
    p.add_argument(
        "--predictor-param",
        action="append",
        metavar="KEY=VALUE",
        help="predictor constructor argument (repeatable)",
    )
    p.add_argument(
        "--barrier",
        default=None,
        help="registered barrier name replacing the paper's APF barrier (see "
        "`conformal-control plugins --role barrier`)",
    )
    p.add_argument(
        "--barrier-param",
        action="append",
        metavar="KEY=VALUE",
        help="barrier constructor argument in SI units (repeatable; needs --barrier)",
    )
    for role, what in (
        ("safety-filter", "safety filter (default qp)"),
        ("reference", "reference controller (default attractive_field)"),
        ("dynamics", "robot dynamics (default velocity_tracking)"),
        ("loss", "loss (default cbf_gap; e.g. collision, distance_shortfall)"),
    ):
        p.add_argument(f"--{role}", default=None, help=f"registered {what}")
        p.add_argument(
            f"--{role}-param",
            action="append",
            metavar="KEY=VALUE",
            help=f"{role.replace('-', ' ')} constructor argument in SI units (repeatable)",
        )
    p.add_argument(
        "--fallback",
        default=None,
        help="what the safety filter does when the constraints are infeasible at lambda "
        "(default lambda_search; see `conformal-control plugins`)",
    )
    p.add_argument("--epsilon", type=float, default=None, help="target average loss")
    p.add_argument(
        "--eta",
        type=float,
        default=None,
        help="learning rate (SDD scenes: per frame; built-in scene: 1/s)",
    )
    p.add_argument(
        "--tau",
        type=float,
        default=None,
        help="sampling period (SDD scenes: frames; built-in scene: s)",
    )
    p.add_argument("--no-learning", action="store_true", help="keep lambda fixed (noLearn)")
    p.add_argument(
        "--rule",
        default="fixed_eta",
        help="registered update rule: fixed_eta (the paper's, default), decaying_eta, pid, "
        "dtaci, aci, ... (see `conformal-control plugins`)",
    )
    p.add_argument(
        "--rule-param",
        action="append",
        metavar="KEY=VALUE",
        help="update-rule constructor argument, in the scene's units (repeatable; lists "
        "comma-separated, e.g. gammas=0.1,1,10)",
    )
    p.add_argument(
        "--lambda-safe",
        type=float,
        default=None,
        help="lambda known/estimated to be safe (scene units): report the Theorem-2 bound",
    )
    p.add_argument("--frames", type=int, default=None, help="simulate at most N frames")
    p.add_argument("--seed", type=int, default=0, help="seed (built-in scene, predictors)")
    p.add_argument("--out", default=None, help="run directory (default runs/<scene>-<time>)")
    p.add_argument(
        "--param",
        action="append",
        metavar="KEY=VALUE",
        help="any other parameter, in the scene's units (repeatable); "
        "see `conformal-control params`",
    )
    p.add_argument("--start", type=_pair, default=None, help="start as image fractions fx,fy")
    p.add_argument(
        "--goal",
        type=_pair,
        action="append",
        default=None,
        help="goal as image fractions fx,fy (repeat for waypoints)",
    )
    p.add_argument("--start-frame", type=int, default=None, help="video frame the robot starts")
    p.add_argument("--no-plot", action="store_true", help="skip plot.png")
    _multi_args(p)


def _predictor_params(args: argparse.Namespace) -> dict:
    """``--predictor-param`` values; a trainable predictor (lstm, sklearn) without
    ``weights`` gets cached weights trained on all of ETH/UCY (trained on first use)."""
    from .. import registry
    from .predictors import cached_weights, trainable_defaults

    pp = key_values(args.predictor_param, "--predictor-param")
    cls = registry.get("predictor", args.predictor)
    if getattr(cls, "trainable", False) and pp.get("weights") is None:
        trainable_defaults(cls, pp, args.seed, 8, 12)
        train_params = {k: v for k, v in pp.items() if k != "weights"}
        pp["weights"] = str(
            cached_weights(
                args.predictor, "sdd:any", args.data_root, train_params, args.seed, 8, 12
            )
        )
    return pp


@_run_args.handler
def _run(args: argparse.Namespace) -> int:
    from ..data import load_scene
    from ..sim.episode import run_episode
    from ..sim.rundir import write_run_dir

    params = key_values(args.param, "--param")
    roles = {}
    for role in ("barrier", "safety_filter", "reference", "dynamics", "loss"):
        given = key_values(getattr(args, f"{role}_param"), f"--{role.replace('_', '-')}-param")
        name = getattr(args, role)
        if given and not name:
            flag = role.replace("_", "-")
            raise ValueError(f"--{flag}-param needs --{flag} NAME")
        roles[role] = name
        roles[f"{role}_params"] = given
    for name in ("epsilon", "eta", "tau"):
        value = getattr(args, name)
        if value is not None:
            params[name] = int(value) if name == "tau" and float(value).is_integer() else value
    scene = load_scene(
        args.scene,
        args.data_root,
        start=args.start,
        goals=args.goal,
        start_frame=args.start_frame,
        seed=args.seed,
    )
    if args.robots is not None or args.robots_file is not None:  # several robots: --robots
        rule_params = key_values(args.rule_param, "--rule-param")
        return _run_multi(args, scene, params, roles, rule_params, _predictor_params(args))
    result = run_episode(
        scene,
        args.predictor,
        params,
        learn=not args.no_learning,
        max_frames=args.frames,
        seed=args.seed,
        predictor_params=_predictor_params(args),
        extra_config={"command": ["conformal-control", *sys.argv[1:]], "data_root": args.data_root},
        rule=args.rule,
        rule_params=key_values(args.rule_param, "--rule-param"),
        lambda_safe=args.lambda_safe,
        fallback=args.fallback,
        **roles,
    )
    out = args.out or Path("runs") / (
        f"{scene.name.replace(':', '_')}-{_dt.datetime.now():%Y%m%d-%H%M%S}"
    )
    out = write_run_dir(result, out, plot=not args.no_plot)
    m = result.metrics
    print(m.format())
    if not m["epsilon_attainable"]:
        print(
            f"warning: epsilon={m['epsilon']} is not attainable: it is at or below the "
            f"feasibility floor s(-a*h_max)={m['epsilon_floor']:.4f} (lambda_floor="
            f"{m['lambda_floor']:g} {m.unit('lambda_floor')}): lambda is added to every sensed "
            "agent's constraint and a far agent's row fails below lambda_floor; raise epsilon "
            "or a (see the Controller page of the docs, 'Feasibility floor')",
            file=sys.stderr,
        )
    print(f"results written to {out}")
    return 0


# ------------------------------------------------------------------ several robots (--robots)
def _multi_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group(
        "several robots",
        "M robots, each its own conformal CBF controller, no communication (see the "
        "Multi-robot page of the docs); the scene's own start and goal define the default "
        "layout",
    )
    g.add_argument("--robots", type=int, default=None, metavar="M", help="number of robots (1-20)")
    g.add_argument(
        "--robot-layout",
        choices=("scene", "antipodal"),
        default="scene",
        help="scene: robot 0 does the scene's task, robot i the same task rotated by 2 pi i/M "
        "about its midpoint; antipodal: on a circle (--radius, --center), each to the "
        "opposite point",
    )
    g.add_argument("--radius", type=float, default=None, help="antipodal circle radius (m)")
    g.add_argument(
        "--center", type=_pair, default=None, help="antipodal circle centre, image fractions fx,fy"
    )
    g.add_argument(
        "--robots-file",
        default=None,
        metavar="FILE.json",
        help='explicit tasks: {"units": "m" or "fraction", "robots": [{"start": [x, y], '
        '"goals": [[x, y], ...]}, ...]}',
    )
    g.add_argument(
        "--sensor-history",
        choices=("tracked", "observed"),
        default="tracked",
        help="histories handed to each robot's predictor: as tracked (the single-robot "
        "sensor) or only where the robot itself had the agent in range",
    )


def _run_multi(
    args: argparse.Namespace,
    scene: Any,
    params: dict[str, Any],
    roles: dict[str, Any],
    rule_params: dict[str, Any],
    predictor_params: dict[str, Any],
    out: Path | None = None,
) -> int:
    """``run --robots``: the run's scene, parameters and roles, as ``_run`` prepared them."""
    from ..sim.multi import load_robots_file, run_multi

    tasks: dict[str, Any] = {}
    if args.robots_file is not None:
        if args.robot_layout != "scene" or args.radius is not None or args.center is not None:
            raise ValueError(
                "--robots-file gives the tasks: drop --robot-layout, --radius, --center"
            )
        starts, goals = load_robots_file(args.robots_file, scene)
        tasks = {"starts": starts, "goals": goals, "robots": args.robots}
    else:
        center = None
        if args.center is not None:
            if scene.extent is None:
                raise ValueError(f"scene {scene.name} has no extent: --center needs one")
            center = (args.center[0] * scene.extent[0], args.center[1] * scene.extent[1])
        tasks = {
            "robots": args.robots,
            "layout": args.robot_layout,
            "radius": args.radius,
            "center": center,
        }
    result = run_multi(
        scene,
        **tasks,
        predictor=args.predictor,
        params=params,
        learn=not args.no_learning,
        max_frames=args.frames,
        seed=args.seed,
        predictor_params=predictor_params,
        rule=args.rule,
        rule_params=rule_params,
        lambda_safe=args.lambda_safe,
        fallback=args.fallback,
        sensor_history=args.sensor_history,
        extra_config={"command": ["conformal-control", *sys.argv[1:]], "data_root": args.data_root},
        **roles,
    )
    if out is None:
        out = (
            Path(args.out)
            if args.out
            else Path("runs")
            / (
                f"{scene.name.replace(':', '_')}-{result.metrics.n_robots}robots-"
                f"{_dt.datetime.now():%Y%m%d-%H%M%S}"
            )
        )
    out = result.save(out)
    print(result.summary_table())
    print(result.metrics.format())
    print(f"results written to {out}")
    return 0
