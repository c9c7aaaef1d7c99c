"""``conformal-control bench``: the closed-loop safety benchmark on real crowds.

``bench scenarios`` lists (or regenerates) a suite, ``bench methods`` lists the methods,
``bench shifts`` the predictor shifts, ``bench tune`` chooses each family's setting on the
dev split, ``bench run`` runs shifts x scenarios x methods on the sweep runner (resumable),
``bench report`` writes the leaderboards, tables and figures from the stored rows.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from . import add_data_root, command, crowd_choices, key_values, positive_int

#: The default suite (``conformal_control.experiments.bench.suite.DEFAULT_SUITE``; not imported
#: here so
#: that ``--help`` stays fast).
SUITE = "crossings-v2"


@command("bench", "closed-loop safety benchmark on real crowds (scenario suites)")
def _bench_args(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="bench_command", metavar="SUBCOMMAND")
    sc = sub.add_parser(
        "scenarios",
        help="list a suite's scenarios, or regenerate it from the data",
        description=(
            "List the scenarios of a shipped suite (one line each), or regenerate the suite "
            "from the data and compare it byte for byte with the shipped manifest."
        ),
    )
    sc.add_argument("--suite", default=SUITE, help=f"suite name (default {SUITE})")
    sc.add_argument("--split", choices=("dev", "test"), help="only this split")
    sc.add_argument("--summary", action="store_true", help="counts per source and split only")
    sc.add_argument(
        "--regenerate",
        action="store_true",
        help="regenerate from --data-root and compare with the shipped manifest (slow: "
        "runs the nolearn baseline on every scenario)",
    )
    add_data_root(sc, " for --regenerate")
    sc.add_argument(
        "--recording",
        action="append",
        metavar="ID",
        help="with --regenerate: only this recording (repeatable), e.g. sdd:nexus/video3",
    )
    sc.add_argument("--output", default=None, help="with --regenerate: write the manifest here")
    sc.add_argument(
        "-j",
        "--workers",
        type=positive_int,
        default=1,
        help="with --regenerate: processes for the nolearn episodes (default 1)",
    )

    me = sub.add_parser(
        "methods",
        help="list the benchmark's methods with their plugins and parameters",
        description="Every method family and its settings (SI units), with the plugins it uses.",
    )
    me.add_argument("--json", action="store_true", help="machine-readable output")

    sub.add_parser(
        "shifts",
        help="list the predictor shifts (--shift)",
        description="The named predictor shifts of `bench run --shift`, with what they do.",
    )

    tu = sub.add_parser(
        "tune",
        help="choose each method family's setting on the dev split (writes tuned.json)",
        description=(
            "Run every tuned family's grid on a split (default dev) under the nominal "
            "predictor and choose one setting per family by one rule: the highest success "
            "rate, ties by fewer collision frames per scenario, then shorter time to goal, "
            "then the first setting of the grid. Writes OUT/tuned.json; `bench run --tuned "
            "OUT` uses it (by default `bench run` uses the values shipped for the suite)."
        ),
    )
    tu.add_argument("--suite", default=SUITE, help=f"suite name (default {SUITE})")
    tu.add_argument("--split", default="dev", choices=("dev", "test"), help="split (default dev)")
    tu.add_argument(
        "--methods",
        default=None,
        help=(
            "comma-separated families to tune (default: fixed,conformal,acp,inflated,"
            "conformal_dtaci_floor)"
        ),
    )
    add_data_root(tu)
    tu.add_argument("--executor", default="batch", choices=("batch", "process", "serial", "dask"))
    tu.add_argument("-j", "--workers", type=int, default=None, help="worker processes")
    tu.add_argument("--limit", type=int, default=None, help="only the first N scenarios")
    tu.add_argument("--out", required=True, help="tuning folder (runs and tuned.json)")
    tu.add_argument(
        "--progress",
        choices=("on", "off"),
        default=None,
        help="progress on stderr (a bar on a terminal, a line every 10 s with the time left "
        "when redirected)",
    )

    ru = sub.add_parser(
        "run",
        help="run scenarios x methods (resumable; failures isolated)",
        description=(
            "Run every scenario of a suite split with every method on the sweep runner. "
            "Finished episodes are skipped on a rerun into the same --out."
        ),
    )
    ru.add_argument("--suite", default=SUITE, help=f"suite name (default {SUITE})")
    ru.add_argument(
        "--split", default="test", choices=("dev", "test", "all"), help="split (default test)"
    )
    ru.add_argument(
        "--methods",
        default=None,
        help=(
            "comma-separated method families, or 'all' (default: nolearn,fixed,conformal,"
            "acp,inflated,conformal_dtaci_floor; see `bench methods`)"
        ),
    )
    ru.add_argument(
        "--shift",
        default="nominal",
        metavar="NAME[,NAME]",
        help="predictor shifts to run (default nominal; see `bench shifts`)",
    )
    ru.add_argument(
        "--tuned",
        default="default",
        metavar="FILE|default|none",
        help=(
            "tuned settings: a `bench tune` folder or its tuned.json, 'default' (the values "
            "shipped for the suite) or 'none' (every family's default settings)"
        ),
    )
    ru.add_argument(
        "--grid",
        action="append",
        metavar="FAMILY=V1,V2",
        help="override a family's settings, e.g. conformal=-0.2,-0.1 (repeatable)",
    )
    ru.add_argument(
        "--predictor",
        default=None,
        help="registered predictor (default constant_velocity; for fcp-planar a comma-"
        "separated list, default recorded,constant_velocity)",
    )
    ru.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="run parameter in SI applied to every method, e.g. K_rep=0.3 (repeatable); with "
        "--robots the reciprocal runs' options, e.g. floor_margin=0 or priority=robots",
    )
    ru.add_argument(
        "--crowd",
        default="replay",
        choices=crowd_choices(),
        help="pedestrians replayed, or reacting to the robot (default replay)",
    )
    add_data_root(ru)
    ru.add_argument(
        "--executor",
        default=None,
        choices=("batch", "process", "serial", "dask"),
        help=(
            "batch (default): the runs the lockstep engine supports (replayed or reactive "
            "crowd, "
            "constant-velocity, oracle or recorded predictor and every --shift compiled, "
            "another fast predictor called in process, any update rule, gap or "
            "collision loss, exact 2-D filter with any fallback, the cbf and acp families: "
            "every method but the MPC families) many at once in this process, with the same "
            "metrics, the others on a process pool; "
            "process: one episode per task on a process pool; "
            "serial: one by one in this process; dask: a Dask cluster (the batched runs "
            "in chunks, each on a worker's own engine; default with --scheduler)"
        ),
    )
    ru.add_argument("-j", "--workers", type=positive_int, default=None, help="worker processes")
    ru.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="run on the Dask cluster at ADDRESS (e.g. tcp://head:8786; implies --executor "
        "dask): workers need the package, the data root and --out on a shared file system",
    )
    ru.add_argument("--limit", type=positive_int, default=None, help="only the first N scenarios")
    ru.add_argument(
        "--datasets",
        default=None,
        help="fcp-planar(-dense) only: comma-separated datasets (default all)",
    )
    ru.add_argument(
        "--seeds",
        default=None,
        help="fcp-planar(-dense) only: comma-separated random states, each scenario once per seed "
        "(default 0)",
    )
    ru.add_argument("--out", required=True, help="benchmark folder")
    ru.add_argument(
        "--progress",
        choices=("on", "off"),
        default=None,
        help="progress on stderr (a bar on a terminal, a line every 10 s with the time left "
        "when redirected)",
    )
    ru.add_argument(
        "--robots",
        default=None,
        metavar="M[,M]",
        help="fleets of M robots (2-20) on the multi-robot suite (multi-crossings-v1, derived "
        "from the crossing suite; see the Multi-robot page)",
    )
    ru.add_argument(
        "--reciprocity",
        default="solo,none,reciprocal",
        metavar="solo,none,reciprocal",
        help="with --robots: how the robots treat each other (default all three, paired by "
        "entry; solo: each robot alone on its own task, the fleet's baseline)",
    )
    ru.add_argument(
        "--information",
        default="plan",
        choices=("position", "velocity", "plan"),
        help="with --robots: what reciprocal robots know of each other (default plan)",
    )
    ru.add_argument(
        "--lambda-scope",
        default="pedestrians",
        choices=("pedestrians", "robots", "both"),
        help="with --robots: the rows lambda is the slack of (default pedestrians)",
    )

    re_ = sub.add_parser(
        "report",
        help="leaderboard, paired comparison and figures from a benchmark folder",
        description=(
            "Build leaderboard.md/.csv, per_scene.md/.csv, frontier.png and "
            "success_vs_epsilon.png from the stored per-episode rows of a benchmark folder."
        ),
    )
    re_.add_argument("folder", help="a `bench run` folder")
    re_.add_argument("--out", default=None, help="report folder (default FOLDER/report)")
    re_.add_argument("--baseline", default="nolearn", help="method compared against")
    re_.add_argument("--title", default=None, help="title of the leaderboard and figures")
    re_.add_argument(
        "--tune-folder",
        default=None,
        help="the `bench tune` folder whose time counts in the run-time target",
    )
    re_.add_argument(
        "--tuned",
        default=None,
        metavar="FILE|default",
        help=(
            "label the members of these tuned values as the tuned methods instead of the "
            "values the run recorded (a `bench tune` folder or its tuned.json, or 'default'); "
            "for rows run before a family was added to the tuned file"
        ),
    )


@_bench_args.handler
def _bench(args: argparse.Namespace) -> int:
    if args.bench_command == "scenarios":
        return _scenarios(args)
    if args.bench_command == "methods":
        return _methods(args)
    if args.bench_command == "shifts":
        return _shifts()
    if args.bench_command == "tune":
        return _tune(args)
    if args.bench_command == "run":
        return _run(args)
    if args.bench_command == "report":
        return _report(args)
    print(
        "usage: conformal-control bench {scenarios,methods,shifts,tune,run,report} ... "
        "(see `conformal-control bench --help`)",
        file=sys.stderr,
    )
    return 2


def _methods(args: argparse.Namespace) -> int:
    import json

    from ...experiments.bench.methods import FAMILIES, available, expand_methods

    methods = expand_methods(FAMILIES)
    if args.json:
        rows = [{**m.as_dict(), "unavailable": available(m)} for m in methods]
        print(json.dumps(rows, indent=2, default=str))
        return 0
    for fam in FAMILIES.values():
        members = [m for m in methods if m.family == fam.name]
        first = members[0]
        print(f"{fam.name}: {fam.description}")
        if fam.setting is not None:
            print(f"  settings ({fam.meaning}): {', '.join(m.setting for m in members)}")
            if fam.tune:
                ref = " (bench run runs the whole grid: a reference)" if fam.reference else ""
                grid = ", ".join(fam.method(v).setting for v in fam.tune)
                print(f"  tuned by `bench tune` over: {grid}{ref}")
        plugins = {"rule": first.rule, **dict(first.roles)}
        if first.predictor:
            plugins["predictor"] = first.predictor
        print(f"  plugins: {', '.join(f'{k}={v}' for k, v in plugins.items())}")
        params = {**dict(first.params), **{f"rule.{k}": v for k, v in first.rule_params.items()}}
        if params:
            shown = ", ".join(
                f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in params.items()
            )
            print(f"  parameters (SI): {shown}; learning: {first.learn}")
        why = available(first)
        if why:
            print(f"  UNAVAILABLE: {why}")
    return 0


def _shifts() -> int:
    from ...experiments.bench.shifts import SHIFTS

    for sh in SHIFTS.values():
        what = "unchanged" if sh.predictor is None else f"{sh.predictor} {dict(sh.params)}"
        if sh.name == "learned":
            what = "recorded (Trajectron++ predictions from the data folder)"
        cover = "" if sh.recordings is None else f"; only {', '.join(sh.recordings)}"
        print(f"{sh.name}: {sh.description}\n  predictor: {what}{cover}")
    return 0


def _grids(items: list[str] | None) -> dict[str, list[Any]]:
    from ...runs.params import parse_value

    out: dict[str, list[Any]] = {}
    for item in items or []:
        fam, eq, values = item.partition("=")
        if not eq or not values:
            raise ValueError(f"--grid expects FAMILY=V1,V2, got {item!r}")
        out[fam.strip()] = [parse_value(v) for v in values.split(",") if v.strip()]
    return out


def _families(text: str | None, default: tuple[str, ...]) -> list[str]:
    from ...experiments.bench.methods import FAMILIES

    if not text:
        return list(default)
    if text.strip() == "all":
        return list(FAMILIES)
    return [m.strip() for m in text.split(",") if m.strip()]


def _progress(value: str | None) -> bool | None:
    return None if value is None else value == "on"


def _tune(args: argparse.Namespace) -> int:
    from ...experiments.bench.tune import DEFAULT_TUNED, tune

    res = tune(
        args.out,
        suite=args.suite,
        split=args.split,
        families=_families(args.methods, DEFAULT_TUNED),
        data_root=args.data_root,
        executor=args.executor,
        workers=args.workers,
        progress=_progress(args.progress),
        limit=args.limit,
    )
    print(res.summary())
    return 0


def _run(args: argparse.Namespace) -> int:
    if args.suite == "fcp-planar-dense":  # the planar protocol, a start every 20 steps
        from ...experiments.bench.planar_dense import run_command as run_dense

        split = "test" if args.split is None else args.split
        return run_dense(
            args.out,
            args.methods,
            args.predictor,
            args.data_root,
            args.datasets,
            args.seeds,
            split,
        )
    if args.suite == "fcp-planar":  # the ETH/UCY planar protocol (its own world and table)
        from ...experiments.bench.planar import run_command

        return run_command(
            args.out, args.methods, args.predictor, args.data_root, args.datasets, args.seeds
        )
    from ...core.spec import RunSpec
    from ...experiments.bench.methods import DEFAULT_METHODS
    from ...experiments.bench.shifts import parse_shifts
    from ...experiments.bench.suite import run_bench

    if args.robots is not None:  # several robots: the multi-robot suite
        from ...experiments.bench.multi import run_command as run_multi_command

        families = _families(args.methods, ("nolearn", "conformal"))
        settings = key_values(args.set, "--set")
        return run_multi_command(args, SUITE, families, _grids(args.grid), settings)

    shifts = [s.name for s in parse_shifts(args.shift)]
    res = run_bench(
        args.out,
        suite=args.suite,
        split=None if args.split == "all" else args.split,
        methods=_families(args.methods, DEFAULT_METHODS),
        grids=_grids(args.grid),
        shifts=shifts,
        tuned=args.tuned,
        base=RunSpec(
            params=key_values(args.set, "--set"),
            predictor=args.predictor or "constant_velocity",
            crowd=args.crowd,
            units="si",
        ),
        data_root=args.data_root,
        executor=_executor(args),
        workers=args.workers,
        scheduler=args.scheduler,
        progress=_progress(args.progress),
        limit=args.limit,
    )
    print(res.summary())
    return 0 if res.failed == 0 and not res.unfinished else 1


def _executor(args: argparse.Namespace) -> str:
    """``--executor``, ``dask`` with ``--scheduler``, else ``batch``."""
    from ...core.exceptions import InputError

    if args.scheduler is None:
        return str(args.executor or "batch")
    if not args.scheduler.strip():  # "" used to start a local cluster without a word
        raise InputError(
            "--scheduler is empty: give the scheduler's address (tcp://host:8786), or leave it out"
        )
    if args.executor not in (None, "dask"):
        raise InputError(f"--scheduler runs on a Dask cluster: drop --executor {args.executor}")
    return "dask"


def _report(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from ...experiments.bench.report import write_report
    from ...experiments.bench.suite import (
        incomplete_notice,
        read_bench,
        read_rows,
        unfinished_episodes,
    )

    folder = Path(args.folder)
    from ...experiments.bench.planar import is_planar_folder, report_command
    from ...experiments.bench.planar_dense import is_dense_folder
    from ...experiments.bench.planar_dense import report_command as dense_report_command

    if is_dense_folder(folder):
        return dense_report_command(args.folder, args.out)
    if is_planar_folder(folder):
        return report_command(args.folder, args.out)
    from ...experiments.bench.multi import is_multi_folder
    from ...experiments.bench.multi import report_command as multi_report

    if is_multi_folder(folder):
        return multi_report(folder, args.out)
    from ...io.plotting.jobs import prepare

    # the figure process imports matplotlib on the other core while the rows are read
    prepare(("conformal_control.experiments.bench.report",))
    rows = read_rows(folder)
    bench = read_bench(folder)
    if args.tuned is not None:
        from ...experiments.bench.report import with_tuned

        bench, missing = with_tuned(bench, args.tuned, rows)
        for fam, name in missing:
            print(
                f"warning: --tuned: family {fam}'s tuned member {name} has no rows in "
                f"{folder}: the report shows no tuned member for it",
                file=sys.stderr,
            )
    tune_wall = None
    if args.tune_folder:
        path = Path(args.tune_folder)
        path = path / "tuned.json" if path.is_dir() else path
        tune_wall = float(json.loads(path.read_text())["wall_s"])
    out = Path(args.out) if args.out else folder / "report"
    title = args.title or f"Benchmark: {folder.name}"
    # the rows hold the latest record of every key: the journal is parsed once
    notice = incomplete_notice(*unfinished_episodes(folder, done=(r["key"] for r in rows)))
    files = write_report(
        rows,
        out,
        baseline=args.baseline,
        title=title,
        bench=bench,
        tune_wall=tune_wall,
        notice=notice,
    )
    print((out / "leaderboard.md").read_text())
    print((out / "targets.md").read_text())
    print("wrote " + ", ".join(str(f) for f in files.values()))
    return 0


def _scenarios(args: argparse.Namespace) -> int:
    from ...data.suites import load_suite

    if args.regenerate:
        return _regenerate(args)
    suite = load_suite(args.suite)
    if args.recording or args.output:
        raise ValueError("--recording and --output go with --regenerate")
    rows = suite.table(args.split)
    if not args.summary:
        print("id\tsplit\tscene\tstart_frame\tmax_frames\tn_crossing\tdensity\tnolearn_collide")
        for r in rows:
            collide = "-" if r["nolearn_collide"] is None else r["nolearn_collide"]
            print(
                f"{r['id']}\t{r['split']}\t{r['scene']}\t{r['start_frame']}\t{r['max_frames']}\t"
                f"{r['n_crossing']}\t{r['density']}\t{collide}"
            )
    for row in suite.summary(args.split):
        print(
            f"# {row['source']:8s} {row['split']:5s} {row['scenarios']:4d} scenario(s), "
            f"{row['nolearn_collision']:4d} with a nolearn collision"
        )
    n_col = sum(row["nolearn_collision"] for row in suite.summary(args.split))
    print(f"# {suite.name}: {len(rows)} scenario(s), {n_col} with a nolearn collision")
    return 0


def _regenerate(args: argparse.Namespace) -> int:
    from ...experiments.bench.generator import regenerate_suite

    done = regenerate_suite(
        args.suite,
        args.data_root,
        recordings=args.recording,
        workers=args.workers,
        progress=lambda line: print(line, flush=True),
    )
    if args.output:
        with open(args.output, "w") as fh:
            fh.write(done.text)
        print(f"wrote {args.output}")
    print(
        f"regenerated {done.n_scenarios} scenario(s) ({done.n_collisions} with a nolearn "
        f"collision) from {len(done.manifest['recordings'])} recording(s) in "
        f"{done.wall_s:.1f} s"
    )
    if done.compared is None:
        print(f"no shipped manifest of {args.suite} to compare with")
        return 0
    if done.same:
        print(f"byte-identical to {done.compared}")
        return 0
    print(f"DIFFERS from {done.compared}", file=sys.stderr)
    return 1
