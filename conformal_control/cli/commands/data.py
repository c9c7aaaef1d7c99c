"""``conformal-control fetch-data``: download the data with checksums."""

from __future__ import annotations

import argparse

from . import check_writable, command


@command("fetch-data", "download SDD and ETH/UCY files and verify their checksums")
def _fetch_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--dest",
        default=None,
        help="data folder to create/complete (unset: the per-user data folder, which every "
        "command reads when neither --data-root nor $CONFORMAL_CONTROL_DATA is given)",
    )
    p.add_argument(
        "--only",
        action="append",
        metavar="SEL",
        help="sdd, ethucy, external, sdd:<scene>_<video> (e.g. sdd:nexus_4), ethucy:<scene> "
        "or external:<folder> (trajectron-ethucy, fcp-planar: mirror only)",
    )
    p.add_argument(
        "--mirror",
        default=None,
        help="folder or URL laid out like the data folder, copied verbatim",
    )
    p.add_argument("--force", action="store_true", help="download even verified files")
    p.add_argument("--dry-run", action="store_true", help="list what would be fetched")


@_fetch_args.handler
def _fetch(args: argparse.Namespace) -> int:
    from ...core.progress import is_quiet
    from ...data.fetch import fetch, plan
    from ...data.paths import ENV_VAR, user_data_dir

    dest = args.dest if args.dest is not None else str(user_data_dir())
    if args.dry_run:
        items = list(plan(args.only, args.mirror))
        print(f"would fetch {len(items)} file(s) into {dest} (paths below are relative to it):")
        for item in items:
            source = item.url or "mirror only (pass --mirror DIR)"
            print(f"{item.path}  <- {source}" + (" (metres -> pixels)" if item.convert else ""))
        return 0
    check_writable(dest, "data folder")
    counts = fetch(
        dest, only=args.only, mirror=args.mirror, force=args.force, progress=not is_quiet()
    )
    if args.dest is None:
        use = f"every command reads it unless --data-root or ${ENV_VAR} says otherwise"
    else:
        use = f"use --data-root {dest} or {ENV_VAR}={dest}"
    skipped = (
        f", {counts['mirror_only']} mirror-only file(s) of external/ not fetched (copy them "
        "with --mirror DIR)"
        if counts.get("mirror_only")
        else ""
    )
    print(
        f"{counts['downloaded']} file(s) downloaded, {counts['verified_existing']} already "
        f"present and verified{skipped}, in {dest}; {use}"
    )
    return 0
