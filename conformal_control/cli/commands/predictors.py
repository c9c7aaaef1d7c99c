"""``conformal-control eval-predictor`` and ``train-predictor``.

A *trainable* predictor class declares ``trainable=True`` (its capabilities), accepts a
``weights`` constructor argument (a folder written by its ``save``), and implements
``fit(history, future, dt) -> self`` on windows of (N, obs, 2) / (N, horizon, 2) and
``save(folder)``.
"""

from __future__ import annotations

import argparse
import csv
import json
import time
from pathlib import Path

from ...core.spec import RunContext
from ...predictors.training import cached_weights, evaluate_with_progress, train, trainable_defaults
from . import add_data_root, check_writable, command, command_line, key_values


def _dataset(text: str) -> str:
    """argparse type: a data set's one name (aliases resolved by the data catalog)."""
    from ...core.exceptions import InputError
    from ...data.catalog import dataset_name

    try:
        return dataset_name(text)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--dataset",
        required=True,
        type=_dataset,
        help="ethucy:<split> (eth, hotel, univ, zara1, zara2: leave-one-out; a recording's "
        "name, ethucy:crowds_zara01, is its split), or an SDD scene (sdd:<scene>/video<N>, "
        "nexus_4)",
    )
    add_data_root(p)
    p.add_argument("--obs", type=int, default=8, help="observed samples (0.4 s apart)")
    p.add_argument("--horizon", type=int, default=12, help="predicted samples (0.4 s apart)")
    p.add_argument("--seed", type=int, default=0, help="seed (training, subsampling)")
    p.add_argument(
        "--param", action="append", metavar="KEY=VALUE", help="predictor argument (repeatable)"
    )


@command("eval-predictor", "ADE/FDE of a predictor on ETH/UCY or an SDD scene (CSV in --out)")
def _eval_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--predictor", required=True, help="registered predictor name")
    _common(p)
    p.add_argument("--max-windows", type=int, default=None, help="seeded subsample of windows")
    p.add_argument(
        "--label", default=None, help="name of the row in the CSV (default: the predictor name)"
    )
    p.add_argument("--out", default=None, help="folder for results.csv and config.json")


@_eval_args.handler
def _eval(args: argparse.Namespace) -> int:
    from ...core import registry
    from ...predictors.evaluation import dataset_windows

    if args.out:
        check_writable(args.out, "results folder")
    params = key_values(args.param, "--param")
    cls = registry.get("predictor", args.predictor)
    registry.check_params("predictor", args.predictor, cls, params)
    if cls.capabilities.trainable:
        trainable_defaults(cls, params, args.seed, args.obs, args.horizon)
    else:  # the seed, to a predictor that declares it takes one
        params = RunContext(seed=args.seed).arguments(cls, params)
    if cls.capabilities.trainable and params.get("weights") is None:
        params["weights"] = str(
            cached_weights(
                args.predictor,
                args.dataset,
                args.data_root,
                params,
                args.seed,
                args.obs,
                args.horizon,
            )
        )
    predictor = registry.create("predictor", args.predictor, **params)
    win = dataset_windows(args.dataset, args.data_root, args.obs, args.horizon)
    if args.max_windows is not None:
        win = win.subsample(args.max_windows, seed=args.seed)
    t0 = time.perf_counter()
    res = evaluate_with_progress(predictor, win, f"eval {args.predictor} on {args.dataset}")
    wall = time.perf_counter() - t0
    row = {
        "predictor": args.label or args.predictor,
        "dataset": args.dataset,
        "ade": round(res["ade"], 4),
        "fde": round(res["fde"], 4),
        "n": res["n"],
    }
    print(
        f"{row['predictor']} {row['dataset']}: ADE {row['ade']:.3f} m  FDE {row['fde']:.3f} m  "
        f"(n={row['n']}, {wall:.1f} s) {res['info'] or ''}"
    )
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        path = out / "results.csv"
        new = not path.exists()
        with path.open("a", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(row))
            if new:
                w.writeheader()
            w.writerow(row)
        cfg = {
            **row,
            "params": predictor.get_params(),
            "obs": args.obs,
            "horizon": args.horizon,
            "dt": win.dt,
            "seed": args.seed,
            "max_windows": args.max_windows,
            "data_meta": win.meta,
            "info": res["info"],
            "wall_s": round(wall, 2),
            "command": command_line(args),
        }
        tag = f"{row['predictor']}-{args.dataset.replace(':', '_')}"
        (out / f"config-{tag}.json").write_text(json.dumps(cfg, indent=2, default=str))
        print(f"results appended to {path}")
    return 0


@command("train-predictor", "train a learned predictor (lstm, sklearn) and save its weights")
def _train_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("predictor", help="trainable predictor name (lstm, sklearn)")
    _common(p)
    p.add_argument("--out", required=True, help="folder for the weights")


@_train_args.handler
def _train(args: argparse.Namespace) -> int:
    check_writable(args.out, "weights folder")
    params = key_values(args.param, "--param")
    out = train(
        args.predictor,
        args.dataset,
        args.data_root,
        args.out,
        params,
        args.seed,
        args.obs,
        args.horizon,
        command=command_line(args),
    )
    info = json.loads((out / "training.json").read_text())
    print(
        f"trained {args.predictor} on {info['n_windows']} windows of {info['training_source']} "
        f"in {info['fit_s']} s -> {out}"
    )
    return 0
