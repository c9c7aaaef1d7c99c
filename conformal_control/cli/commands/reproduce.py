"""``conformal-control reproduce table1|table2|forms|all``: the paper's tables on SDD data."""

from __future__ import annotations

import argparse
import sys

from . import add_data_root, check_writable, command, key_values
from .sweep import add_executor_args


@command("reproduce", "run the paper's Tables I and II (both variants) and compare")
def _reproduce_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "targets",
        nargs="+",
        choices=("table1", "table2", "forms", "all"),
        help="table1 (gates_1), table2 (nexus_4), forms (nexus_4 raw vs TrajNet), or all",
    )
    add_data_root(p)
    p.add_argument(
        "--predictor",
        default="constant_velocity",
        help="registered predictor (the paper: darts, from plugins/darts)",
    )
    p.add_argument(
        "--predictor-param", action="append", metavar="KEY=VALUE", help="predictor argument"
    )
    p.add_argument("--out", default="reproduce", help="output folder (reused to resume)")
    add_executor_args(
        p,
        auto="serial when the predictor is a fast one (constant_velocity, oracle, var), "
        "else process",
    )
    p.add_argument(
        "--frames", type=int, default=None, help="simulate at most N frames per run (smoke test)"
    )
    p.add_argument("--seed", type=int, default=0, help="seed handed to stochastic predictors")
    p.add_argument(
        "--variant",
        action="append",
        choices=("printed", "published"),
        default=None,
        help="run only this variant (repeatable; default both): printed = the paper's "
        "parameters, published = a = 10 as the published code ran",
    )
    p.add_argument("--no-figures", action="store_true", help="tables only")
    p.add_argument(
        "--progress",
        choices=("auto", "on", "off"),
        default="auto",
        help="progress on stderr (auto, on: a bar on a terminal, a line every 10 s with the "
        "time left when redirected)",
    )


@_reproduce_args.handler
def _reproduce(args: argparse.Namespace) -> int:
    from ...core.progress import is_quiet
    from ...experiments.reproduce import reproduce

    check_writable(args.out, "output folder")
    shown = {"auto": None, "on": True, "off": False}[args.progress]
    s = reproduce(
        args.targets,
        args.out,
        data_root=args.data_root,
        predictor=args.predictor,
        predictor_params=key_values(args.predictor_param, "--predictor-param"),
        executor=args.executor,
        workers=args.workers,
        scheduler=args.scheduler,
        frames=args.frames,
        seed=args.seed,
        figures=not args.no_figures,
        variants=args.variant,
        progress=False if is_quiet() else shown,
    )
    worst = s["max_abs_lavg_minus_eps_eta100"]
    print(
        f"{s['runs']} runs ({s['skipped']} reused, {s['ran']} ran, {s['failed']} failed) on "
        f"{s['executor']} in {s['wall_s']:.1f} s; update identity "
        f"{'holds' if s['identity_ok'] else 'FAILS'} on every learning row; gt rows "
        f"{'use the true future' if s['oracle_ok'] else 'FAIL the oracle check'}"
        + (f"; max |l_avg - eps| at eta = 100: {worst:.4f}" if worst is not None else "")
    )
    print(f"wrote {', '.join(s['files'])} in {args.out}")
    if s["failed"]:
        print("some runs failed: see the tables and sweep/results.csv", file=sys.stderr)
    return 0 if (s["identity_ok"] and s["oracle_ok"] and not s["failed"]) else 1
