"""Choose the flagship's defaults for real crowds on the benchmark's DEV split.

Stage 1 (``--stage barrier``): the noLearn controller (lambda = 0) over a grid of barrier
gain K_rep (m^2), class-K slope a (1/s) and infeasibility fallback. Stage 2
(``--stage learning``): for the best barrier settings, the conformal controller over
epsilon, eta and tau against noLearn and fixed lambdas.

Stage ``grid`` crosses both at once on a subset: noLearn, a fixed lambda and the conformal
controller at two epsilons, each over K_rep x a (the lambda-search fallback), on every
``--every``-th dev scenario.

Every configuration runs every dev scenario of ``crossings-v1`` through the public
benchmark runner (resumable: rerun the same command to finish an interrupted study), and
the leaderboard of each stage is written next to the results. The test split is never
touched here.

    python benchmarks/tune_defaults.py --stage barrier --out tune/barrier -j 2
    python benchmarks/tune_defaults.py --stage learning --out tune/learning -j 2 \\
        --set K_rep=0.2 --set a=100 --fallback relax
"""

from __future__ import annotations

import argparse
import itertools
import time
from pathlib import Path

from conformal_control.experiments.bench.methods import FRAME, Method
from conformal_control.experiments.bench.report import write_report
from conformal_control.experiments.bench.suite import bench_configs, read_rows
from conformal_control.experiments.runner import run_sweep


def barrier_methods(k_reps, slopes, fallbacks) -> list[Method]:
    out = []
    for k, a, fb in itertools.product(k_reps, slopes, fallbacks):
        out.append(
            Method(
                "nolearn",
                f"K_rep={k:g},a={a:g},{fb}",
                "noLearn over the barrier grid",
                learn=False,
                params={"K_rep": k, "a": a},
                roles={"fallback": fb},
            )
        )
    return out


def learning_methods(base: dict, fallback: str, epsilons, etas, taus, lambdas) -> list[Method]:
    roles = {"fallback": fallback}
    out = [Method("nolearn", "", "lambda = 0", learn=False, params=dict(base), roles=roles)]
    for lam in lambdas:
        out.append(
            Method(
                "fixed",
                f"lambda={lam:g}/s",
                "fixed lambda",
                learn=False,
                params={**base, "lambda_init": lam},
                roles=roles,
            )
        )
    for eps, eta, tau in itertools.product(epsilons, etas, taus):
        out.append(
            Method(
                "conformal",
                f"eps={eps:g},eta={eta:g},tau={tau:g}",
                "fixed-eta rule on the gap loss",
                params={**base, "epsilon": eps, "eta": eta, "tau": tau},
                roles=roles,
            )
        )
    return out


def grid_methods(k_reps, slopes, epsilons, lambdas) -> list[Method]:
    out = []
    for k, a in itertools.product(k_reps, slopes):
        base = {"K_rep": k, "a": a}
        tag = f"K_rep={k:g},a={a:g}"
        out.append(Method("nolearn", tag, "lambda = 0", learn=False, params=base))
        for lam in lambdas:
            out.append(
                Method(
                    "fixed",
                    f"{tag},lambda={lam:g}",
                    "fixed lambda",
                    learn=False,
                    params={**base, "lambda_init": lam},
                )
            )
        for eps in epsilons:
            out.append(
                Method(
                    "conformal",
                    f"{tag},eps={eps:g}",
                    "fixed-eta rule on the gap loss",
                    params={**base, "epsilon": eps, "eta": 1 / FRAME},
                )
            )
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    p.add_argument("--stage", choices=("barrier", "learning", "grid"), required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--data-root", default=None)
    p.add_argument("-j", "--workers", type=int, default=2)
    p.add_argument("--limit", type=int, default=None, help="first N dev scenarios only")
    p.add_argument("--every", type=int, default=1, help="every N-th dev scenario only")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--fallback", default="lambda_search")
    p.add_argument("--eps", type=float, nargs="+", default=[-0.2, -0.1, -0.05, 0.0])
    p.add_argument("--eta-per-frame", type=float, nargs="+", default=[0.1, 1.0])
    p.add_argument("--tau-frames", type=float, nargs="+", default=[4, 12])
    p.add_argument("--lambdas", type=float, nargs="*", default=[-3.0, -10.0, -30.0])
    args = p.parse_args()
    base = {k: float(v) for k, v in (s.split("=", 1) for s in args.set)}
    if args.stage == "barrier":
        methods = barrier_methods(
            (0.05, 0.2, 0.5), (1 / FRAME, 100.0, 10 / FRAME), ("lambda_search", "relax", "brake")
        )
    elif args.stage == "grid":
        methods = grid_methods((0.05, 0.2), (100.0, 10 / FRAME), (-0.1, 0.0), (-30.0,))
    else:
        methods = learning_methods(
            base,
            args.fallback,
            epsilons=tuple(args.eps),
            etas=tuple(e / FRAME for e in args.eta_per_frame),
            taus=tuple(t * FRAME for t in args.tau_frames),
            lambdas=tuple(args.lambdas),
        )
    scenarios = None
    if args.every > 1:
        from conformal_control.data.suites import load_suite

        dev = load_suite("crossings-v1").scenarios_for("dev")
        scenarios = [sc.id for sc in dev[:: args.every]]
    configs = bench_configs(
        "crossings-v1",
        "dev",
        methods,
        data_root=args.data_root,
        limit=args.limit,
        scenarios=scenarios,
    )
    t0 = time.perf_counter()
    rep = run_sweep(
        configs, args.out, "process", workers=args.workers, plot="none", summary_plot=False
    )
    print(rep.summary())
    rows = read_rows(args.out)
    files = write_report(
        rows, Path(args.out) / "report", title=f"Tuning on dev: {args.stage}", baseline="x"
    )
    print((Path(args.out) / "report" / "leaderboard.md").read_text())
    print(f"{len(configs)} episodes in {time.perf_counter() - t0:.0f} s; {files['frontier.png']}")


if __name__ == "__main__":
    main()
