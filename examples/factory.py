"""The CDT paper's factory example through the generic conformal loop.

lambda is the machine speed, defects are Binomial(p, min(1, b lambda)), the loss is the
defect fraction and the target epsilon = 0.05. Runs every update rule on the same seeded
defect draws and prints, per rule, the average defect fraction over the runs, its worst
run, how often the Theorem-2 bound (fixed-step rules) or the rule's long-run bound held,
and the average speed (the productivity the rule buys with its defects).

    python examples/factory.py                 # the paper's setting: 100 runs of T = 500
    python examples/factory.py --runs 5 --T 100
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any

import numpy as np

from conformal_control.core.update_rules import DecayingEtaRule, DtACIRule, FixedEtaRule, PIDRule
from conformal_control.families.domains.factory import run_factory

EPSILON, ETA, LAMBDA_1 = 0.05, 0.1, 0.1


def rules() -> dict[str, Any]:
    """The rules compared, all at epsilon = 0.05 and lambda_1 = 0.1."""
    return {
        "fixed_eta (paper)": lambda: FixedEtaRule(epsilon=EPSILON, eta=ETA, lambda_init=LAMBDA_1),
        "decaying_eta": lambda: DecayingEtaRule(
            epsilon=EPSILON, eta=ETA, power=0.5, lambda_init=LAMBDA_1
        ),
        "pid": lambda: PIDRule(epsilon=EPSILON, eta=ETA, K_I=0.05, C_sat=1.0, lambda_init=LAMBDA_1),
        "dtaci": lambda: DtACIRule(
            epsilon=EPSILON, gammas=(0.01, 0.03, 0.1, 0.3), lambda_init=LAMBDA_1
        ),
    }


def main(argv: Sequence[str] | None = None) -> list[dict[str, Any]]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--T", type=int, default=500)
    ap.add_argument("--p", type=int, default=10)
    ap.add_argument("--b", type=float, default=0.75)
    args = ap.parse_args(argv)
    rows = []
    for name, make in rules().items():
        figs = [
            run_factory(make(), T=args.T, p=args.p, b=args.b, seed=seed)[1]
            for seed in range(args.runs)
        ]
        l_avg = np.array([f["l_avg"] for f in figs])
        t2 = [f["theorem2_holds"] for f in figs if f["theorem2_holds"] is not None]
        lr = [f["long_run_holds"] for f in figs if f["long_run_holds"] is not None]
        rows.append(
            {
                "rule": name,
                "guarantee": figs[0]["guarantee"],
                "l_avg_mean": float(l_avg.mean()),
                "l_avg_sd": float(l_avg.std()),
                "l_avg_max": float(l_avg.max()),
                "theorem2_bound": figs[0]["theorem2_bound"],
                "theorem2_held": f"{sum(t2)}/{len(t2)}" if t2 else "-",
                "long_run_held": f"{sum(lr)}/{len(lr)}" if lr else "-",
                "speed_avg": float(np.mean([f["speed_avg"] for f in figs])),
            }
        )
    print(f"factory: {args.runs} runs x T={args.T}, p={args.p}, b={args.b}, epsilon={EPSILON}")
    print(
        "| rule | guarantee | mean l_avg (sd) | worst l_avg | Thm-2 bound | Thm-2 held "
        "| long-run bound held | mean speed |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        bound = "-" if r["theorem2_bound"] is None else f"{r['theorem2_bound']:.4f}"
        print(
            f"| {r['rule']} | {r['guarantee']} | {r['l_avg_mean']:.4f} ({r['l_avg_sd']:.4f}) "
            f"| {r['l_avg_max']:.4f} | {bound} | {r['theorem2_held']} | {r['long_run_held']} "
            f"| {r['speed_avg']:.4f} |"
        )
    return rows


if __name__ == "__main__":
    main()
