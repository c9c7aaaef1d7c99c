"""``conformal-control eval-predictor`` and ``train-predictor``.

A *trainable* predictor class sets ``trainable = True``, accepts a ``weights`` constructor
argument (a folder written by its ``save``), and implements
``fit(history, future, dt) -> self`` on windows of (N, obs, 2) / (N, horizon, 2) and
``save(folder)``.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import sys
import time
from pathlib import Path
from typing import Any

from . import command, key_values


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--dataset", required=True, help="ethucy:<scene> or sdd:<scene> / nexus_4")
    p.add_argument("--data-root", default=None, help="data folder (or its ethucy/ or sdd/)")
    p.add_argument("--obs", type=int, default=8, help="observed samples (0.4 s apart)")
    p.add_argument("--horizon", type=int, default=12, help="predicted samples (0.4 s apart)")
    p.add_argument("--seed", type=int, default=0, help="seed (training, subsampling)")
    p.add_argument(
        "--param", action="append", metavar="KEY=VALUE", help="predictor argument (repeatable)"
    )


def trainable_defaults(
    cls: type, params: dict[str, Any], seed: int, obs: int, horizon: int
) -> None:
    names = cls._param_names()
    for key, value in (("random_state", seed), ("obs", obs), ("horizon", horizon)):
        if key in names:
            params.setdefault(key, value)


def train(
    name: str,
    dataset: str,
    data_root: str | None,
    out: str | Path,
    params: dict[str, Any],
    seed: int = 0,
    obs: int = 8,
    horizon: int = 12,
) -> Path:
    """Train predictor ``name`` on the training windows of ``dataset`` and save it to ``out``."""
    from .. import registry
    from ..predictors.evaluation import training_windows

    cls = registry.get("predictor", name)
    if not getattr(cls, "trainable", False):
        raise ValueError(f"predictor {name!r} is not trainable")
    win = training_windows(dataset, data_root, obs, horizon)
    if len(win) == 0:
        raise ValueError(f"no training windows for {dataset}")
    p = {k: v for k, v in params.items() if k != "weights"}
    trainable_defaults(cls, p, seed, obs, horizon)
    model = registry.create("predictor", name, **p)
    t0 = time.perf_counter()
    model.fit(win.history, win.future, win.dt)
    out = Path(out)
    model.save(out)
    info = {
        "predictor": name,
        "params": model.get_params(),
        "dataset": dataset,
        "training_source": win.source,
        "training_files": win.meta.get("files"),
        "n_windows": len(win),
        "obs": obs,
        "horizon": horizon,
        "seed": seed,
        "fit_s": round(time.perf_counter() - t0, 2),
        "command": ["conformal-control", *sys.argv[1:]],
    }
    (out / "training.json").write_text(json.dumps(info, indent=2, default=str))
    return out


def cached_weights(
    name: str,
    dataset: str,
    data_root: str | None,
    params: dict[str, Any],
    seed: int,
    obs: int,
    horizon: int,
) -> Path:
    """Weights for a trainable predictor, trained on first use and cached."""
    from .. import registry
    from ..predictors.cache import cache_dir

    if dataset.partition(":")[0] != "ethucy":
        dataset = "sdd:any"  # every SDD scene trains on all of ETH/UCY: one cached model
    # key on every constructor parameter (defaults included), so changed defaults retrain
    full = registry.create("predictor", name, **params).get_params()
    full.pop("weights", None)
    key = json.dumps(
        {"n": name, "d": dataset, "p": full, "s": seed, "o": obs, "h": horizon},
        sort_keys=True,
        default=str,
    )
    digest = hashlib.sha256(key.encode()).hexdigest()[:12]
    folder = cache_dir("weights") / f"{name}-{dataset.replace(':', '_')}-{digest}"
    if not (folder / "training.json").is_file():
        print(f"training {name} for {dataset} (first use) -> {folder}", file=sys.stderr)
        train(name, dataset, data_root, folder, params, seed, obs, horizon)
    return folder


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
    from .. import registry
    from ..predictors.evaluation import dataset_windows, evaluate_predictor

    params = key_values(args.param, "--param")
    cls = registry.get("predictor", args.predictor)
    if getattr(cls, "trainable", False):
        trainable_defaults(cls, params, args.seed, args.obs, args.horizon)
    elif "random_state" in cls._param_names():
        params.setdefault("random_state", args.seed)
    if getattr(cls, "trainable", False) and params.get("weights") is None:
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
    res = evaluate_predictor(predictor, win)
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
            "command": ["conformal-control", *sys.argv[1:]],
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
    )
    info = json.loads((out / "training.json").read_text())
    print(
        f"trained {args.predictor} on {info['n_windows']} windows of {info['training_source']} "
        f"in {info['fit_s']} s -> {out}"
    )
    return 0
