"""Speed of the vectorised crossing-scene generator against the per-step loop it replaced.

The baseline is the loop generator kept as the bit-identity reference in
``tests/data/test_synthetic.py`` (loaded from there, not copied); both are timed in the
same run on the same seeds, and their outputs are compared byte for byte. Usage::

    python benchmarks/bench_synthetic.py --seeds 10 --repeat 3
"""

from __future__ import annotations

import argparse
import importlib.util
import time
from pathlib import Path

from conformal_control.data.synthetic import crossing_tracks

ROOT = Path(__file__).resolve().parents[1]


def _reference():
    spec = importlib.util.spec_from_file_location(
        "_synthetic_reference", ROOT / "tests" / "data" / "test_synthetic.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod._reference_tracks


def _best(fn, seeds, repeat, **kw) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        for s in seeds:
            fn(seed=s, **kw)
        best = min(best, time.perf_counter() - t0)
    return best / len(seeds)


def measure(seeds: list[int], repeat: int, **kw) -> dict:
    """Best time per scene of the loop generator and of the vectorised one, same seeds.

    The outputs of the first three seeds are compared byte for byte first (``SystemExit``
    if they differ). Returns ``loop_s`` and ``vectorised_s`` (seconds per scene) and
    ``n_tracks`` (tracks of the first seed); ``kw`` goes to both generators.
    """
    reference = _reference()
    for s in seeds[:3]:
        ref, new = reference(seed=s, **kw), crossing_tracks(seed=s, **kw).tracks
        same = list(ref) == list(new) and all(
            ref[k][0].tobytes() == new[k][0].tobytes()
            and ref[k][1].tobytes() == new[k][1].tobytes()
            for k in ref
        )
        if not same:
            raise SystemExit(f"outputs differ for seed {s} ({kw})")
    old = _best(reference, seeds, repeat, **kw)
    vec = _best(lambda **k: crossing_tracks(**k), seeds, repeat, **kw)
    n = len(crossing_tracks(seed=seeds[0], **kw).tracks)
    return {"loop_s": old, "vectorised_s": vec, "n_tracks": n}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    seeds = list(range(args.seeds))
    for label, kw in (("default (10 fps, 72 s)", {}), ("30 fps", {"fps": 30.0})):
        r = measure(seeds, args.repeat, **kw)
        old, vec = r["loop_s"], r["vectorised_s"]
        print(
            f"{label:24s} loop {1e3 * old:7.1f} ms/scene  vectorised {1e3 * vec:6.1f} ms/scene  "
            f"speed-up x{old / vec:.1f}  ({r['n_tracks']} tracks for seed 0; bit-identical)"
        )


if __name__ == "__main__":
    main()
