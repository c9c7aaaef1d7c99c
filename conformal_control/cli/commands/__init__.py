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
from pathlib import Path
from typing import Any, Protocol, cast

__all__ = [
    "COMMANDS",
    "add_data_root",
    "check_writable",
    "command",
    "command_line",
    "crowd_choices",
    "crowd_params",
    "finite_float",
    "key_values",
    "load_all",
    "load_command",
    "non_negative_int",
    "plugin_key_values",
    "plugin_params",
    "positive_int",
    "scene_data_root",
]

Handler = Callable[[argparse.Namespace], int]
COMMANDS: dict[str, tuple[str, Callable[[argparse.ArgumentParser], None], Handler]] = {}


class ArgsAdder(Protocol):
    """An argument-adder decorated by :func:`command`: it also has ``handler``."""

    #: Decorator registering the command's handler.
    handler: Callable[[Handler], Handler]

    def __call__(self, parser: argparse.ArgumentParser, /) -> None: ...


def command(
    name: str, help: str
) -> Callable[[Callable[[argparse.ArgumentParser], None]], ArgsAdder]:
    """Decorate an argument-adder; then decorate the handler with ``adder.handler``."""

    def deco(add_args: Callable[[argparse.ArgumentParser], None]) -> ArgsAdder:
        def register(handler: Handler) -> Handler:
            COMMANDS[name] = (help, add_args, handler)
            return handler

        # the function itself gets the attribute ArgsAdder declares (no wrapper object)
        adder = cast(ArgsAdder, add_args)
        adder.handler = register
        return adder

    return deco


def key_values(items: Sequence[str] | None, flag: str) -> dict[str, Any]:
    """Parse repeated ``KEY=VALUE`` options into a dict of typed values.

    A key given twice with different values keeps the last one, with an
    :class:`~conformal_control.core.exceptions.OptionConflictWarning`.
    """
    import warnings

    from ...core.exceptions import InputError, OptionConflictWarning
    from ...runs.params import parse_value

    out: dict[str, Any] = {}
    raw: dict[str, str] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise InputError(f"{flag} expects KEY=VALUE, got {item!r}")
        if key in raw and raw[key] != value.strip():
            warnings.warn(
                OptionConflictWarning(
                    f"{flag} {key} given twice ({key}={raw[key]} and {key}={value.strip()}); "
                    f"using the last, {key}={value.strip()}"
                ),
                stacklevel=2,
            )
        raw[key] = value.strip()
        out[key] = parse_value(value)
    return out


def add_data_root(parser: argparse.ArgumentParser, purpose: str = "") -> None:
    """``--data-root DIR``, with the same help everywhere: the three places the data is
    looked for, in order (:mod:`conformal_control.data.paths`)."""
    parser.add_argument(
        "--data-root",
        default=None,
        metavar="DIR",
        help=f"data folder{purpose} (holding sdd/ and ethucy/, or one of them); unset: "
        "$CONFORMAL_CONTROL_DATA, else the per-user data folder that fetch-data fills",
    )


def plugin_key_values(
    items: Sequence[str] | None, flag: str, classes: Sequence[type]
) -> dict[str, Any]:
    """:func:`key_values` for the constructor arguments of ``classes`` (a plugin, a crowd
    and its model): values with an SI unit suffix (``max_speed=2m/s``, ``delay_s=500ms``)
    are converted to the number in the unit the class documents, and a suffix that does
    not fit is an error now, before anything runs."""
    from ...data.units import documented_unit, si_value

    out = key_values(items, flag)
    for key, value in out.items():
        if not any(_takes(c, key) for c in classes):
            continue  # not an argument at all: the plugin's own check names it, did-you-mean
        unit = next((u for c in classes if (u := documented_unit(c, key)) is not None), None)
        out[key] = si_value(key, value, unit, flag)
    return out


def plugin_params(role: str, name: str, items: Sequence[str] | None, flag: str) -> dict[str, Any]:
    """``--<role>-param`` values for the plugin registered as ``name``: each typed by the
    plugin's constructor (:func:`plugin_key_values`) and checked against it.

    Parameters
    ----------
    role, name : str
        The plugin's role and registered name.
    items : list of str or None
        The ``KEY=VALUE`` items given.
    flag : str
        The option, for error messages.
    """
    from ...core import registry

    cls = registry.get(role, name)
    pp = plugin_key_values(items, flag, [cls])
    registry.check_params(role, name, cls, pp)
    return pp


def crowd_choices() -> list[str]:
    """The crowds a ``--crowd`` option accepts (``replay``, every registered crowd model,
    ``mixed``: :func:`~conformal_control.core.registry.crowd_names`)."""
    from ...core import registry

    return registry.crowd_names()


def crowd_params(crowd: str, items: Sequence[str] | None) -> dict[str, Any]:
    """``--crowd-param`` values for the crowd ``crowd``: typed by the crowd's classes, a
    unit suffix converted to the crowd's SI units (the ``mixed`` crowd's own ``radius``, in
    metres), checked before the scene is loaded.

    Parameters
    ----------
    crowd : str
        The crowd (``replay``, ``social_force``, ``orca``, ``mixed``, ...).
    items : list of str or None
        The ``KEY=VALUE`` items given.
    """
    from ...core import registry
    from ...data.units import si_value
    from ...world.crowds.crowd import Crowd

    given = key_values(items, "--crowd-param")
    model = given.get("model", "social_force") if crowd == "mixed" else crowd
    known = model in registry.names("crowd")
    classes: list[type] = [Crowd, *([registry.get("crowd", model)] if known else [])]
    radius = given.pop("radius", None) if crowd == "mixed" else None
    kept = [i for i in items or [] if i.partition("=")[0].strip() != "radius"]
    pp = plugin_key_values(kept if crowd == "mixed" else items, "--crowd-param", classes)
    if radius is not None:  # the mixed crowd's own radius (m)
        pp["radius"] = si_value("radius", radius, "m", "--crowd-param")
    return pp


def scene_data_root(scene: str, data_root: str | None) -> str | None:
    """The data folder a run on ``scene`` reads (absolute; None for the built-in scene).

    Parameters
    ----------
    scene : str
        The scene's name.
    data_root : str or None
        The ``--data-root`` given.
    """
    if scene == "crossing":
        return None
    from ...data.paths import resolve_data_root

    return str(resolve_data_root(data_root).resolve())


def _takes(cls: type, key: str) -> bool:
    """Whether ``cls(**{key: ...})`` is accepted by its constructor's signature."""
    import inspect

    try:
        params = inspect.signature(cls).parameters
    except (TypeError, ValueError):  # no introspectable signature: let the class decide
        return True
    return key in params or any(p.kind is p.VAR_KEYWORD for p in params.values())


def finite_float(text: str) -> float:
    """argparse type: a finite number (no nan, no inf)."""
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def finite_quantity(text: str) -> float | str:
    """argparse type: a finite number, or a number with a unit suffix (``30/s``,
    ``0.4s``, ``12frames``), kept as text for the parameter's own conversion."""
    import re

    try:
        return finite_float(text)
    except argparse.ArgumentTypeError:
        if re.fullmatch(r"\s*[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?\s*[^\d\s].*", text):
            return text.strip()
        raise


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}")
    return value


def non_negative_int(text: str) -> int:
    """argparse type: an integer >= 0."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {text!r}")
    return value


def command_line(args: argparse.Namespace) -> list[str]:
    """The command line of this invocation (for config files), as typed."""
    return ["conformal-control", *getattr(args, "argv", [])]


def check_writable(path: str | Path, what: str = "output folder") -> Path:
    """Check, before any work is done, that folder ``path`` can be created and written.

    Creates nothing: a probe file is written into the nearest existing ancestor and
    removed at once.

    Raises
    ------
    OutputNotWritableError
        If ``path`` is a file, lies below a file, or its nearest existing folder cannot
        be written.
    """
    import tempfile

    from ...core.exceptions import OutputNotWritableError

    path = Path(path).expanduser()
    if path.exists() and not path.is_dir():
        raise OutputNotWritableError(f"cannot write the {what} {path}: it is a file")
    probe = path
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if not probe.is_dir():
        raise OutputNotWritableError(
            f"cannot create the {what} {path}: {probe} is a file, not a folder"
        )
    try:
        with tempfile.TemporaryFile(dir=probe):
            pass
    except OSError as exc:
        raise OutputNotWritableError(
            f"cannot write the {what} {path}: {probe} is not writable ({exc.strerror or exc})"
        ) from None
    return path


def load_command(
    name: str,
) -> dict[str, tuple[str, Callable[[argparse.ArgumentParser], None], Handler]] | None:
    """Import only the module named like command ``name`` (``-`` read as ``_``) and return
    a table holding just that command, or None when no such module registers it (then
    :func:`load_all` is needed). A run of one command builds its parser alone: importing
    every command module and building every parser is a tenth of a short ``run``."""
    import importlib.util

    module = f"{__name__}.{name.replace('-', '_')}"
    if name.startswith(("_", ".")) or importlib.util.find_spec(module) is None:
        return None
    importlib.import_module(module)
    if name not in COMMANDS:
        return None
    return {name: COMMANDS[name]}


def load_all() -> dict[str, tuple[str, Callable[[argparse.ArgumentParser], None], Handler]]:
    """Import every command module of this package and return the command table."""
    for mod in pkgutil.iter_modules(__path__):
        importlib.import_module(f"{__name__}.{mod.name}")
    return COMMANDS
