"""``conformal-control plugins``: every registered plugin by role, optionally contract-checked."""

from __future__ import annotations

import argparse
import time

from . import command


@command("plugins", "list the registered plugins by role (--check runs the contract kit)")
def _plugins_args(p: argparse.ArgumentParser) -> None:
    from ...core import registry

    p.add_argument(
        "--role",
        choices=[*registry.ROLES, *registry.RENAMED_ROLES],  # 0.2's names: deprecated
        default=None,
        help="only this role",
    )
    p.add_argument(
        "--check",
        action="store_true",
        help="run the contract checks (conformal_control.testing) on every plugin and print "
        "pass/fail per plugin; exit status 1 if any check fails",
    )


def _truncate(text: str, width: int) -> str:
    return text if len(text) <= width else text[: width - 3] + "..."


@_plugins_args.handler
def _plugins(args: argparse.Namespace) -> int:
    from ...core import registry

    roles = [registry.role_name(args.role)] if args.role else list(registry.ROLES)
    n_fail = n_plugins = n_unavailable = 0
    for role in roles:
        print(f"{role} ({registry.ROLES[role]}):")
        items = registry.entries(role)
        if not items:
            print("  (none)")
        for entry in items:
            n_plugins += 1
            origin = entry.origin + (f" {entry.version}" if entry.version else "")
            if not entry.available:
                n_unavailable += 1
                print(f"  {entry.name:<20} UNAVAILABLE [{origin}]")
                print(f"  {'':<20} {entry.error}")
                continue
            print(
                f"  {entry.name:<20} {_truncate(entry.summary().replace('``', ''), 72)}  [{origin}]"
            )
            if args.check:
                n_fail += _check(role, entry.load(), bool(getattr(args, "verbose", 0)))
    clashes = [c for c in registry.clashes() if c.role in roles]
    if clashes:
        print("name clashes (first registration kept):")
        for c in clashes:
            print(f"  {c}")
    if args.check:
        status = "all passed" if not n_fail else f"{n_fail} failed"
        print(
            f"contract checks: {n_plugins - n_unavailable} plugins checked, {status}"
            + (f"; {n_unavailable} unavailable (not checked)" if n_unavailable else "")
        )
    return 1 if n_fail else 0


def _check(role: str, cls: type, verbose: bool) -> int:
    """Run the role's checks on ``cls``; print a summary line, failures in full."""
    from ...testing import checks_for

    t0 = time.perf_counter()
    results = checks_for(role).run(cls)
    wall = time.perf_counter() - t0
    failed = [r for r in results if not r.passed]
    n_inst = len({r.plugin for r in results})
    verdict = "PASS" if not failed else "FAIL"
    print(
        f"  {'':<20} {verdict}: {len(results) - len(failed)}/{len(results)} checks passed "
        f"({n_inst} instance{'s' if n_inst != 1 else ''}, {wall:.2f} s)"
    )
    for r in results:
        if not r.passed:
            print(f"  {'':<22} FAIL {r.check} [{r.plugin}]: {r.message}")
        elif verbose:
            print(f"  {'':<22} ok   {r.check} [{r.plugin}]")
    return 1 if failed else 0
