"""Time of the contract kit per registered plugin (what ``tests/test_contracts.py`` costs).

Usage::

    python benchmarks/bench_contracts.py [--role ROLE]

Prints, for every registered plugin, the number of (instance, check) pairs, how many pass,
the total wall time and the slowest check; then the grand total. The plugin guideline is
well under 2 s per check (heavy plugins make ``_unit_test_params()`` cheap).
"""

from __future__ import annotations

import argparse
import time

from conformal_control.core import registry
from conformal_control.testing import checks_for, instances


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    parser.add_argument("--role", choices=list(registry.ROLES), default=None)
    args = parser.parse_args()
    total_t = total_n = 0.0
    print(f"{'role':<14} {'plugin':<20} {'checks':>6} {'passed':>6} {'wall s':>7}  slowest check")
    for entry in registry.entries(args.role):
        if not entry.available:
            print(f"{entry.role:<14} {entry.name:<20} unavailable: {entry.error}")
            continue
        cls = entry.load()
        n = passed = 0
        slowest, slowest_t = "", 0.0
        t_plugin = time.perf_counter()
        for obj in instances(cls):
            for check in checks_for(entry.role):
                t0 = time.perf_counter()
                try:
                    check(obj)
                    passed += 1
                except Exception:
                    pass
                dt = time.perf_counter() - t0
                n += 1
                if dt > slowest_t:
                    slowest, slowest_t = check.__name__, dt
        wall = time.perf_counter() - t_plugin
        total_t += wall
        total_n += n
        print(
            f"{entry.role:<14} {entry.name:<20} {n:>6} {passed:>6} {wall:>7.3f}  "
            f"{slowest} ({slowest_t:.3f} s)"
        )
    print(f"total: {int(total_n)} checks in {total_t:.2f} s")


if __name__ == "__main__":
    main()
