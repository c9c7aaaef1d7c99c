"""Subcommands of ``conformal-control``.

Every module in this package contributes subcommands with the :func:`command` decorator;
:func:`load_all` imports them all, so a new command is a new module and nothing else::

    @command("hello", "print a greeting")
    def _args(p: argparse.ArgumentParser) -> None:
        p.add_argument("--name", default="world")

    @_args.handler
    def _hello(args: argparse.Namespace) -> int:
        print(f"hello {args.name}")
        return 0
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
from collections.abc import Callable, Sequence
from typing import Any

__all__ = ["COMMANDS", "command", "key_values", "load_all"]

Handler = Callable[[argparse.Namespace], int]
COMMANDS: dict[str, tuple[str, Callable[[argparse.ArgumentParser], None], Handler]] = {}


def command(name: str, help: str) -> Callable[[Callable[[argparse.ArgumentParser], None]], Any]:
    """Decorate an argument-adder; then decorate the handler with ``adder.handler``."""

    def deco(add_args: Callable[[argparse.ArgumentParser], None]) -> Any:
        def register(handler: Handler) -> Handler:
            COMMANDS[name] = (help, add_args, handler)
            return handler

        add_args.handler = register  # type: ignore[attr-defined]
        return add_args

    return deco


def key_values(items: Sequence[str] | None, flag: str) -> dict[str, Any]:
    """Parse repeated ``KEY=VALUE`` options into a dict of typed values."""
    from ..sim.config import parse_value

    out: dict[str, Any] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"{flag} expects KEY=VALUE, got {item!r}")
        out[key.strip()] = parse_value(value)
    return out


def load_all() -> dict[str, tuple[str, Callable[[argparse.ArgumentParser], None], Handler]]:
    """Import every command module of this package and return the command table."""
    for mod in pkgutil.iter_modules(__path__):
        importlib.import_module(f"{__name__}.{mod.name}")
    return COMMANDS
