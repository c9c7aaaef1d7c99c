"""``conformal-control run``: one episode of the conformal CBF controller.

Before anything is computed the command checks what it can: the output folder is
writable, ``sdd:`` scenes have a start and a goal, options that conflict or have no
effect are reported (warnings), parameters are resolved in the scene's units (unit
suffixes converted, implausible values reported). The episode then shows its progress in
frames. Every run directory's ``config.json`` holds the options as given (``cli``), so
``run --config RUN/config.json`` replays it exactly (options given beside ``--config``
override the stored ones).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import warnings
from pathlib import Path
from typing import Any

from ...core import registry
from ...core.exceptions import ConformalControlDeprecationWarning
from . import (
    add_data_root,
    check_writable,
    command,
    command_line,
    crowd_choices,
    crowd_params,
    finite_float,
    finite_quantity,
    key_values,
    non_negative_int,
    plugin_params,
    positive_int,
    scene_data_root,
)

_ROLES = ("barrier", "safety_filter", "reference", "dynamics", "loss", "family")
#: options that are not part of a run's identity (not stored for --config)
_NOT_STORED = ("out", "config", "argv", "command", "quiet", "verbose", "no_plot")


def _position(text: str) -> str:
    """argparse type: a position as :mod:`~conformal_control.data.positions` reads it
    (``fx,fy`` fractions, ``3.2m,1.0m``, ``120px,300px``), kept as typed (the scene
    converts it; ``config.json`` stores it as given)."""
    from ...core.exceptions import InputError
    from ...data.positions import parse_position

    try:
        return str(parse_position(text, "the position"))
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


@command("run", "run the conformal CBF controller on a scene and write a run directory")
def _run_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--scene",
        default="crossing",
        help="crossing (built-in, no data needed), a paper scene (nexus_4, gates_1, ...), "
        "sdd:<scene>/video<N> (needs --start and --goal) or ethucy:<recording> "
        "(crowds_zara01, ...; see `conformal-control scenes`)",
    )
    add_data_root(p)
    p.add_argument(
        "--config",
        default=None,
        metavar="RUN/config.json",
        help="replay the run that wrote this config.json (options given beside it override)",
    )
    p.add_argument("--predictor", default="constant_velocity", help="registered predictor name")
    p.add_argument(
        "--predictor-param",
        action="append",
        metavar="KEY=VALUE",
        help="predictor constructor argument (repeatable); learned predictors (lstm, "
        "sklearn) take weights=FOLDER from `conformal-control train-predictor`",
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
        ("safety-filter", "safety filter (unset: exact2d; qp = piqp, the general n-D reference)"),
        ("reference", "reference controller (unset: attractive_field)"),
        ("dynamics", "robot dynamics (unset: velocity_tracking)"),
        ("loss", "loss (unset: cbf_gap; e.g. collision, distance_shortfall)"),
        ("family", "decision family (unset: cbf; e.g. acp, mpc, acp_mpc, ecp_mpc)"),
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
        "(unset: lambda_search; see `conformal-control plugins`)",
    )
    p.add_argument(
        "--crowd",
        default="replay",
        choices=crowd_choices(),
        help="pedestrians replayed from the data, or reacting to the robot (social force, "
        "ORCA, or replayed until the robot comes near: mixed)",
    )
    p.add_argument(
        "--crowd-param",
        action="append",
        metavar="KEY=VALUE",
        help="crowd model parameter in SI units, e.g. radius=3 or model=orca for mixed "
        "(repeatable; see the Reactive crowds page)",
    )
    p.add_argument(
        "--epsilon", type=finite_float, default=None, help="target average loss (unset: scene's)"
    )
    p.add_argument(
        "--eta",
        type=finite_quantity,
        default=None,
        help="learning rate (SDD scenes: per frame; built-in scene: 1/s; or with a unit: "
        "30/s, 1/frame; unset: scene's)",
    )
    p.add_argument(
        "--tau",
        type=finite_quantity,
        default=None,
        help="sampling period (SDD scenes: frames; built-in scene: s; or with a unit: 0.4s, "
        "12frames; unset: scene's)",
    )
    p.add_argument(
        "--no-learning",
        "--no-learn",
        dest="no_learning",
        action="store_true",
        help="keep lambda fixed (noLearn); --no-learn is an alias",
    )
    p.add_argument(
        "--rule",
        default="fixed_eta",
        help="registered update rule: fixed_eta (the paper's), decaying_eta, pid, "
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
        type=finite_float,
        default=None,
        help="lambda known/estimated to be safe (scene units): report the Theorem-2 bound "
        "(rules with a fixed step: fixed_eta, aci)",
    )
    p.add_argument("--frames", type=positive_int, default=None, help="simulate at most N frames")
    p.add_argument("--seed", type=int, default=0, help="seed (built-in scene, predictors)")
    p.add_argument("--out", default=None, help="run directory (unset: runs/<scene>-<time>)")
    p.add_argument(
        "--param",
        action="append",
        metavar="KEY=VALUE",
        help="any other parameter, in the scene's units or with a unit suffix (rho0=18m, "
        "rho0=400px, tau=0.4s, tau=12frames, eta=30/s, eta=1/frame); repeatable; "
        "see `conformal-control params --scene NAME`",
    )
    p.add_argument(
        "--start",
        type=_position,
        default=None,
        help="start as fractions fx,fy of the scene (SDD: its image; ETH/UCY: its walkable "
        "box), or in metres 3.2m,1.0m, or pixels 120px,300px (unset: the scene's own; sdd: "
        "scenes need one)",
    )
    p.add_argument(
        "--goal",
        type=_position,
        action="append",
        default=None,
        help="goal, as --start (repeat for waypoints)",
    )
    p.add_argument(
        "--start-frame",
        type=non_negative_int,
        default=None,
        help="video frame the robot starts at (unset: the scene's)",
    )
    p.add_argument("--no-plot", action="store_true", help="skip plot.png")
    _multi_args(p)


# ------------------------------------------------------------------------------ replay
class _OptionsParser(argparse.ArgumentParser):
    """The command's own options, every default suppressed (a parsed namespace holds only
    what was given), errors raised rather than printed, each option recorded by its
    destination: ``options[dest] = (flag, action)`` (``action`` as given to
    ``add_argument``: ``"store_true"``, ``"append"``, ... or None)."""

    def __init__(self) -> None:
        super().__init__(
            prog="conformal-control run", add_help=False, exit_on_error=False, allow_abbrev=False
        )
        self.options: dict[str, tuple[str, str | None]] = {}

    def add_argument(self, *args: Any, **kwargs: Any) -> argparse.Action:
        kwargs["default"] = argparse.SUPPRESS
        action = super().add_argument(*args, **kwargs)
        if action.option_strings:
            kind = kwargs.get("action")
            self.options[action.dest] = (action.option_strings[-1], kind)
        return action

    def add_argument_group(self, *args: Any, **kwargs: Any) -> Any:
        if "options" not in vars(self):  # argparse's own groups, made by its __init__
            return super().add_argument_group(*args, **kwargs)
        return self  # a group only shapes the help, which this parser never prints


def _run_parser() -> _OptionsParser:
    """The command's own parser (:class:`_OptionsParser`): the options :func:`_run_args`
    declares, and ``-q`` / ``-v``."""
    parser = _OptionsParser()
    _run_args(parser)
    parser.add_argument("-q", "--quiet", action="store_true")
    parser.add_argument("-v", "--verbose", action="count")
    return parser


def _explicit_options(argv: list[str]) -> dict[str, Any]:
    """The ``run`` options given on this command line (defaults left out).

    ``argv`` is the whole command line: global flags (``-q``, ``-v``: no values), the
    command name, then the command's own options.
    """
    name = next((i for i, a in enumerate(argv) if not a.startswith("-")), None)
    ns = vars(_run_parser().parse_args(argv[name + 1 :] if name is not None else argv))
    return {k: v for k, v in ns.items() if k not in ("command", "quiet", "verbose")}


def _stored_options(args: argparse.Namespace, data_root: str | None) -> dict[str, Any]:
    """The run's options as a JSON-ready dict (what ``--config`` replays)."""
    out: dict[str, Any] = {}
    for key, value in vars(args).items():
        if key in _NOT_STORED or key.startswith("_"):
            continue
        if isinstance(value, tuple):
            value = list(value)
        elif isinstance(value, list):
            value = [list(v) if isinstance(v, tuple) else v for v in value]
        out[key] = value
    out["data_root"] = data_root
    return out


def _option_text(value: Any) -> str:
    """A stored option value as the command line types it (a pair as ``fx,fy``)."""
    if isinstance(value, (list, tuple)):
        return ",".join(_option_text(v) for v in value)
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise TypeError
    return str(value)


def _replayed_options(stored: dict[str, Any], path: Path) -> dict[str, Any]:
    """The options a config.json stores (its ``cli`` entry), checked as the command line
    checks them: each is turned back into the flags that set it and parsed by the
    command's own parser (types, ranges, choices). Only the options the tool stores are
    applied: an output folder (``out``) never is, nor anything else outside the run's
    identity (unknown keys are reported and skipped).

    Raises
    ------
    InputError
        For a value of the wrong type (``no_learning: "false"``, ``frames: "abc"``): one
        line naming the file, the key and what it must be.
    """
    from ...core.exceptions import IgnoredOptionWarning, InputError

    parser = _run_parser()
    options = {k: v for k, v in parser.options.items() if k not in _NOT_STORED}
    applied: dict[str, Any] = {}
    skipped = []
    for key, value in stored.items():
        option = options.get(key)
        if option is None:
            skipped.append(key)
            continue
        if value is None:
            continue
        flag, kind = option
        where = f"--config {path}: {key}"
        if kind == "store_true":
            if not isinstance(value, bool):
                raise InputError(f"{where} must be true or false, got {value!r}")
            tokens = [flag] if value else []
        else:
            items = value if kind == "append" else [value]
            if not isinstance(items, list):
                raise InputError(f"{where} must be a list, got {value!r}")
            tokens = []
            for item in items:
                try:
                    tokens += [flag, _option_text(item)]
                except TypeError:
                    raise InputError(
                        f"{where} must be {'a list of ' if len(items) > 1 else ''}"
                        f"numbers or text, got {item!r}"
                    ) from None
        try:
            ns = vars(parser.parse_args(tokens))
        except argparse.ArgumentError as exc:
            raise InputError(f"{where}: {exc.message}") from None
        if key in ns:
            applied[key] = ns[key]
    if skipped:
        warnings.warn(
            IgnoredOptionWarning(
                f"--config {path}: {', '.join(sorted(skipped))} "
                f"{'is not an option' if len(skipped) == 1 else 'are not options'} a run "
                "stores, so not replayed"
            ),
            stacklevel=2,
        )
    return applied


#: The largest ``--config`` file read (bytes): a run's ``config.json`` is a few kB.
MAX_CONFIG_BYTES = 16 << 20


def _apply_config(args: argparse.Namespace) -> None:
    """Fill ``args`` from a run's config.json; options given explicitly win."""
    from ...core.exceptions import InputError
    from ...core.fileio import read_limited

    path = Path(args.config).expanduser()
    if path.is_dir():
        path = path / "config.json"
    try:
        # capped, never a FIFO or a device (/dev/zero read until memory ran out)
        raw = read_limited(path, MAX_CONFIG_BYTES, what="--config file")
    except FileNotFoundError:
        raise InputError(f"--config {args.config}: no such file") from None
    try:
        cfg = json.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise InputError(
            f"--config {path}: not a text file (not UTF-8), not a run's config"
        ) from None
    except json.JSONDecodeError as exc:
        raise InputError(
            f"--config {path}: not valid JSON ({exc.msg} at line {exc.lineno})"
        ) from None
    except RecursionError:
        raise InputError(f"--config {path}: nested too deeply to be a run's config") from None
    stored = cfg.get("cli") if isinstance(cfg, dict) else None
    if not isinstance(stored, dict):
        raise InputError(
            f"--config {path} was not written by `conformal-control run` (it has no 'cli' "
            "entry), so it cannot be replayed from the command line"
        )
    replayed = _replayed_options(stored, path)
    explicit = _explicit_options(getattr(args, "argv", []))
    for key, value in replayed.items():
        if key not in explicit:
            setattr(args, key, value)
    for key in ("param", "predictor_param", "rule_param", *(f"{r}_param" for r in _ROLES)):
        if key in explicit and replayed.get(key):
            merged = {i.partition("=")[0].strip(): i for i in replayed[key]}
            merged.update({i.partition("=")[0].strip(): i for i in explicit[key]})
            setattr(args, key, list(merged.values()))


# ------------------------------------------------------------------------------ checks
def _check_options(args: argparse.Namespace, params: dict[str, Any]) -> None:
    """Conflicting, ignored and incomplete options (before anything is loaded)."""
    from ...core.exceptions import IgnoredOptionWarning, InputError, OptionConflictWarning

    if args.scene.startswith("sdd:") and (args.start is None or args.goal is None):
        raise InputError(
            f"scene {args.scene} needs --start fx,fy and --goal fx,fy (fractions of the image "
            "width and height, or metres: 3.2m,1.0m), e.g. --start 0.05,0.5 --goal 0.95,0.5"
        )
    for name in ("epsilon", "eta", "tau"):
        flag = getattr(args, name)
        if flag is not None and name in params and params[name] != flag:
            shown = f"{flag:g}" if isinstance(flag, float) else flag
            warnings.warn(
                OptionConflictWarning(
                    f"--{name} {shown} and --param {name}={params[name]} disagree; using "
                    f"--{name} {shown}"
                ),
                stacklevel=2,
            )
    if args.no_learning:
        ignored = [
            f"--{n.replace('_', '-')}"
            for n in ("eta", "rule_param", "lambda_safe")
            if getattr(args, n) is not None
        ]
        if "eta" in params:
            ignored.append("--param eta")
        if args.rule != "fixed_eta":
            ignored.append("--rule")
        if ignored:
            warnings.warn(
                IgnoredOptionWarning(
                    f"--no-learning keeps lambda fixed, so {', '.join(ignored)} "
                    "has no effect on this run"
                ),
                stacklevel=2,
            )
    if args.lambda_safe is not None and not args.no_learning:
        cls = registry.get("rule", args.rule)
        kind = cls.capabilities.guarantee
        if kind != "identity":
            warnings.warn(
                IgnoredOptionWarning(
                    f"rule {args.rule} has no Theorem-2 bound (its guarantee is {kind!r}; only "
                    "fixed-step rules such as fixed_eta and aci have one), so --lambda-safe "
                    "only counts the updates at or below it"
                ),
                stacklevel=2,
            )
    if args.scene == "crossing" and args.data_root is not None:
        warnings.warn(
            IgnoredOptionWarning(
                "the built-in crossing scene reads no data files, so --data-root is ignored"
            ),
            stacklevel=2,
        )


def _default_out(scene_name: str) -> Path:
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in scene_name)
    return Path("runs") / f"{safe}-{_dt.datetime.now():%Y%m%d-%H%M%S}"


# ------------------------------------------------------------------------------ command
@_run_args.handler
def _run(args: argparse.Namespace) -> int:
    if not args.no_plot and args.robots is None and args.robots_file is None:
        # the run's modules first: the figure process inherits them (its jobs hold objects
        # of their classes), then it imports matplotlib on the other core during the episode
        from ... import data  # noqa: F401
        from ...io.plotting.jobs import prepare, release
        from ...runs import episode  # noqa: F401
        from ...runs.results import rundir  # noqa: F401

        prepare(
            ("conformal_control.io.plotting.guarantee", "conformal_control.io.plotting.distance")
        )
        try:
            return _run_prepared(args)
        finally:
            release()  # not used (an error before the figures): it goes now
    return _run_prepared(args)


def _run_prepared(args: argparse.Namespace) -> int:
    """The command: its options parsed and checked, the run by :func:`conformal_control.run`
    (one robot) or :func:`~conformal_control.runs.fleet.run_multi` (``--robots``), the run
    directory."""
    import logging

    from ...api import run
    from ...runs.results.rundir import write_run_dir

    log = logging.getLogger("conformal_control.run")
    if args.config:
        _apply_config(args)
    out = Path(args.out) if args.out else _default_out(args.scene)
    check_writable(out, "run directory")

    params = key_values(args.param, "--param")
    if "fallback" in params:  # the way of 0.2: the fallback is a role, --fallback NAME
        old_way = str(params.pop("fallback"))
        if args.fallback is not None and args.fallback != old_way:
            from ...core.exceptions import InputError

            raise InputError(
                f"--fallback {args.fallback} and --param fallback={old_way} disagree; give "
                "--fallback NAME only"
            )
        warnings.warn(
            f"--param fallback={old_way} is --fallback {old_way} since 0.3 ("
            "removed in 0.4, not before 2027-06-30)",
            ConformalControlDeprecationWarning,
            stacklevel=2,
        )
        args.fallback = old_way
    _check_options(args, params)
    roles: dict[str, Any] = {}
    for role in _ROLES:
        flag = role.replace("_", "-")
        given = key_values(getattr(args, f"{role}_param"), f"--{flag}-param")
        name = getattr(args, role)
        if given and not name:
            from ...core.exceptions import InputError

            raise InputError(f"--{flag}-param needs --{flag} NAME")
        roles[role] = name
        roles[f"{role}_params"] = given
    for name in ("epsilon", "eta", "tau"):
        value = getattr(args, name)
        if value is not None:
            whole = name == "tau" and isinstance(value, float) and value.is_integer()
            params[name] = int(value) if whole else value
    rule_params = key_values(args.rule_param, "--rule-param")
    settings: dict[str, Any] = dict(
        predictor=args.predictor,
        predictor_params=plugin_params(
            "predictor", args.predictor, args.predictor_param, "--predictor-param"
        ),
        learn=not args.no_learning,
        max_frames=args.frames,
        seed=args.seed,
        rule=args.rule,
        rule_params=rule_params,
        lambda_safe=args.lambda_safe,
        fallback=args.fallback,
        crowd=args.crowd,
        crowd_params=crowd_params(args.crowd, args.crowd_param),
        **roles,
    )
    if args.robots is not None or args.robots_file is not None:  # several robots: --robots
        from ...core.spec import RunSpec

        return _run_multi(args, RunSpec.from_settings(params, **settings), out)
    if args.floor_margin is not None or args.floor_core is not None:
        from ...core.exceptions import InputError

        flag = "--floor-margin" if args.floor_margin is not None else "--floor-core"
        raise InputError(f"{flag} sets the robots' floor rows: it needs --robots M")

    data_root = scene_data_root(args.scene, args.data_root)
    result = run(
        args.scene,
        params=params,
        units="scene",  # --param and the flags are in the scene's units (or carry one)
        **settings,
        data_root=args.data_root,
        start=args.start,
        goal=args.goal,
        start_frame=args.start_frame,
        progress=True,
        extra_config={
            "command": command_line(args),
            "data_root": data_root,
            "cli": _stored_options(args, data_root),
        },
    )
    log.info("writing the run directory %s", out)
    out = write_run_dir(result, out, plot=not args.no_plot)
    print(result.metrics.format())
    print(f"results written to {out}")
    return 0


# ------------------------------------------------------------------ several robots (--robots)
def _multi_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group(
        "several robots",
        "M robots, each its own conformal CBF controller, sharing their robot-robot "
        "constraints (see the Multi-robot page of the docs); the scene's own start and "
        "goal define the default layout",
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
        "--center",
        type=_position,
        default=None,
        help="antipodal circle centre, as --start (fractions fx,fy or metres 3.2m,1.0m)",
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
    g.add_argument(
        "--reciprocity",
        choices=("reciprocal", "none"),
        default="reciprocal",
        help="reciprocal (default): each robot takes its share of every robot pair's "
        "constraint; none: each predicts the others like pedestrians",
    )
    g.add_argument(
        "--information",
        choices=("position", "velocity", "plan"),
        default="plan",
        help="what reciprocal robots know of each other: positions, positions and "
        "velocities (sensed), or positions and the velocities they broadcast (default)",
    )
    g.add_argument(
        "--lambda-scope",
        choices=("pedestrians", "robots", "both"),
        default=None,
        help="the rows lambda is the slack of (default: pedestrians with reciprocity, both "
        "without)",
    )
    g.add_argument(
        "--floor-margin",
        type=float,
        default=None,
        metavar="M",
        help="how far (m, >= 0) beyond the robots' collision distance the reciprocal CBF "
        "robots' floor rows aim, the rows kept when the robot rows give way to the "
        "pedestrians' (default 0.1; 0: the collision distance)",
    )
    g.add_argument(
        "--floor-core",
        choices=("always", "inside", "calm", "ahead", "none"),
        default=None,
        help="which pairs' floor rows keep their cores (half the floor margin) before the "
        "pedestrians' rows give way: every pair's, only pairs already in contact, only "
        "pairs with no pedestrian in contact with either robot, only pairs with none in "
        "contact nor predicted in contact within 1 s (and pairs within the floor "
        "distance), or none "
        "(default: see docs/multi-robot.md)",
    )


def _run_multi(args: argparse.Namespace, spec: Any, out: Path) -> int:
    """``run --robots``: the run's specification (as ``_run_prepared`` built it) with the
    robots' tasks, by :func:`~conformal_control.runs.fleet.run_multi`."""
    from ...runs.fleet import prepare_fleet, run_multi

    scene, spec = prepare_fleet(
        args.scene,
        spec,
        data_root=args.data_root,
        start=args.start,
        goal=args.goal,
        start_frame=args.start_frame,
        robots_file=args.robots_file,
        center=args.center,
        robots=args.robots,
        layout=args.robot_layout,
        radius=args.radius,
        sensor_history=args.sensor_history,
        reciprocity=args.reciprocity,
        information=args.information,
        lambda_scope=args.lambda_scope,
        **({} if args.floor_margin is None else {"floor_margin": args.floor_margin}),
        **({} if args.floor_core is None else {"floor_core": args.floor_core}),
    )
    data_root = scene_data_root(args.scene, args.data_root)
    stored = _stored_options(args, data_root)  # what `run --config` replays
    if args.robots_file is not None:
        stored["robots_file"] = str(Path(args.robots_file).expanduser().resolve())
    result = run_multi(
        scene,
        spec,
        extra_config={
            "command": command_line(args),
            "data_root": data_root,
            "cli": stored,
        },
    )
    out = result.save(out)
    print(result.summary_table())
    print(result.metrics.format())
    print(f"results written to {out}")
    return 0
