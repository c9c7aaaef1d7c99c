"""``conformal-control bench``: the closed-loop safety benchmark (scenario suites)."""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from . import command


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
    sc.add_argument("--suite", default="crossings-v1", help="suite name (default crossings-v1)")
    sc.add_argument("--split", choices=("dev", "test"), help="only this split")
    sc.add_argument("--summary", action="store_true", help="counts per source and split only")
    sc.add_argument(
        "--regenerate",
        action="store_true",
        help="regenerate from --data-root and compare with the shipped manifest (slow: "
        "runs the nolearn baseline on every scenario)",
    )
    sc.add_argument("--data-root", default=None, help="data folder (for --regenerate)")
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
        type=int,
        default=1,
        help="with --regenerate: processes for the nolearn episodes (default 1)",
    )


@_bench_args.handler
def _bench(args: argparse.Namespace) -> int:
    if args.bench_command == "scenarios":
        return _scenarios(args)
    print("usage: conformal-control bench scenarios --suite NAME [...]", file=sys.stderr)
    return 2


def _scenarios(args: argparse.Namespace) -> int:
    from ..data.suites import load_suite

    if args.regenerate:
        return _regenerate(args)
    suite = load_suite(args.suite)
    if args.recording or args.output:
        raise ValueError("--recording and --output go with --regenerate")
    rows = suite.scenarios_for(args.split)
    if not args.summary:
        print("id\tsplit\tscene\tstart_frame\tmax_frames\tn_crossing\tdensity\tnolearn_collide")
        for s in rows:
            collide = "-" if s.nolearn is None else s.nolearn["n_collide"]
            print(
                f"{s.id}\t{s.split}\t{s.scene}\t{s.start_frame}\t{s.max_frames}\t"
                f"{s.stats.get('n_crossing')}\t{s.stats.get('corridor_density')}\t{collide}"
            )
    for row in suite.summary():
        if args.split is None or row["split"] == args.split:
            print(
                f"# {row['source']:8s} {row['split']:5s} {row['scenarios']:4d} scenario(s), "
                f"{row['nolearn_collision']:4d} with a nolearn collision"
            )
    n = len(rows)
    n_col = sum(int(bool(s.collided_nolearn)) for s in rows)
    print(f"# {suite.name}: {n} scenario(s), {n_col} with a nolearn collision")
    return 0


def _regenerate(args: argparse.Namespace) -> int:
    from ..bench.generator import SUITES, generate_suite
    from ..data.suites import dump_manifest, load_suite, suite_names

    if args.suite not in SUITES:
        raise ValueError(
            f"no generator for suite {args.suite!r}; suites with one: {', '.join(SUITES)}"
        )
    t0 = time.perf_counter()
    manifest = generate_suite(
        SUITES[args.suite],
        args.data_root,
        recordings=args.recording,
        workers=args.workers,
        progress=lambda line: print(line, flush=True),
    )
    wall = time.perf_counter() - t0
    text = dump_manifest(manifest)
    if args.output:
        with open(args.output, "w") as fh:
            fh.write(text)
        print(f"wrote {args.output}")
    n = len(manifest["scenarios"])
    n_col = sum(int(s["nolearn"]["n_collide"] > 0) for s in manifest["scenarios"])
    print(
        f"regenerated {n} scenario(s) ({n_col} with a nolearn collision) from "
        f"{len(manifest['recordings'])} recording(s) in {wall:.1f} s"
    )
    if args.suite not in suite_names():
        print(f"no shipped manifest of {args.suite} to compare with")
        return 0
    shipped = load_suite(args.suite).manifest
    if args.recording:
        wanted = set(args.recording)
        same = _entries(shipped, wanted) == _entries(manifest, wanted)
        what = f"the shipped entries of {len(wanted)} recording(s)"
    else:
        same = text == dump_manifest(shipped)
        what = "the shipped manifest"
    if same:
        print(f"byte-identical to {what}")
        return 0
    print(f"DIFFERS from {what}", file=sys.stderr)
    return 1


def _entries(manifest: dict[str, Any], wanted: set[str]) -> list[str]:
    """The serialised recording entries and scenarios of some recordings."""
    import json

    recs = [r for r in manifest["recordings"] if r["id"] in wanted]
    scs = [s for s in manifest["scenarios"] if s["recording"] in wanted]
    return [json.dumps(x, indent=1) for x in (*recs, *scs)]
