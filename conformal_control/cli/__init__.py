"""Command-line interface: ``conformal-control <command>``.

The subcommands live in :mod:`conformal_control.cli.commands`, one module per feature. This
module owns what every command shares:

* global options, accepted before or after the command name: ``--quiet`` (no progress
  bars or notes), ``-v`` / ``-vv`` (diagnostics of the ``conformal_control`` logger);
* warnings (:class:`~conformal_control.core.exceptions.ConformalControlWarning` and any other)
  printed as one line each, ``warning: <message>``;
* errors: an expected failure (bad input or data, a missing or unreadable file, an
  unwritable output, a failed download) prints one line, ``error: <message>``, and exits
  with status 2; an interrupted command exits with 128 + the signal (130 for Ctrl-C, 143
  for SIGTERM) and a sweep's says what its folder holds and how to resume; anything else is
  a bug and says so in one line (``-v`` shows the traceback), exit status 70;
* ``--help`` of every command shows the defaults.
"""

from __future__ import annotations

import argparse
import logging
import re
import sys
import warnings
import weakref
from collections.abc import Sequence
from typing import Any, NoReturn

from .. import __version__

__all__ = ["EXIT_BUG", "EXIT_ERROR", "build_parser", "choice_noun", "describe_error", "main"]

EXIT_ERROR = 2
EXIT_BUG = 70
EXIT_INTERRUPTED = 130


class HelpFormatter(argparse.HelpFormatter):
    """Shows each option's default (``[default: X]``) unless it is None, False or the
    help already states it."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        default = action.default
        if (
            "%(default)" in text
            or "default" in text.lower()
            or default is None
            or default is False
            or default is argparse.SUPPRESS
            or not action.option_strings
            or action.nargs == 0
        ):
            return text
        return f"{text} [default: %(default)s]"


def _is_subcommands(action: argparse.Action) -> bool:
    """Whether ``action`` chooses a subcommand (its choices are the subcommands' parsers)."""
    choices = action.choices
    return isinstance(choices, dict) and any(
        isinstance(v, argparse.ArgumentParser) for v in choices.values()
    )


def choice_noun(action: argparse.Action) -> str:
    """What a value of ``action`` is called in an error: ``command`` for a subcommand,
    else the option's name (``--crowd`` -> ``crowd``, ``--robot-layout`` -> ``robot
    layout``) or the positional argument's metavar or name, singular for a list
    (``targets`` -> ``target``)."""
    if _is_subcommands(action):
        return "command"
    if action.option_strings:
        name = max(action.option_strings, key=len)
        return name.lstrip("-").replace("-", " ")
    name = action.metavar if isinstance(action.metavar, str) else action.dest
    if action.nargs in ("+", "*") and name.endswith("s"):
        name = name[:-1]  # one value of a list: "targets" -> "target"
    return name.lower().replace("_", " ")


#: the message of an unknown choice, found again in ``ArgumentParser.error``
_CHOICE = re.compile(r"^argument [^:]+: (unknown .*?)(?: \[(one of .*)\])?$", re.S)


class ArgumentParser(argparse.ArgumentParser):
    """argparse with one-line errors (``error: ...``); a value that is not one of the
    choices is named by what it is (``unknown crowd 'socialforce'; did you mean
    'social_force'?``), with the closest choice or the list of choices; an unknown option
    gets the closest option of its command (``unknown option '--epsilo'; did you mean
    '--epsilon'?``). Options are never abbreviated (``allow_abbrev=False``): ``--epsilo``
    is not read as ``--epsilon``, so a typo cannot silently set another option."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def parse_known_args(  # type: ignore[override]  # typeshed's overloads; same behaviour
        self, args: Sequence[str] | None = None, namespace: Any = None
    ) -> tuple[Any, list[str]]:
        self._argv = list(sys.argv[1:] if args is None else args)
        return super().parse_known_args(args, namespace)

    def _commands(self, argv: Sequence[str]) -> list[tuple[str, argparse.ArgumentParser]]:
        """The (sub)commands ``argv`` names, outermost first (``bench``, then ``run``)."""
        out: list[tuple[str, argparse.ArgumentParser]] = []
        parser: argparse.ArgumentParser = self
        while True:
            subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
            name = next((a for a in argv if subs and a in subs[0].choices), None)
            if name is None:
                return out
            parser = subs[0].choices[name]
            out.append((name, parser))

    def _options_for(self, argv: Sequence[str]) -> list[str]:
        """The option strings of this parser and of the commands ``argv`` names."""
        parsers = [self, *(p for _, p in self._commands(argv))]
        return [o for p in parsers for a in p._actions for o in a.option_strings]

    def _unknown_options(self, message: str) -> str | None:
        """``unknown option '--epsilo'; did you mean '--epsilon'?`` for argparse's
        ``unrecognized arguments: ...``, or None when no option is among them."""
        import difflib

        if not message.startswith("unrecognized arguments: "):
            return None
        argv = getattr(self, "_argv", [])
        flags = [a.partition("=")[0] for a in argv if a.startswith("--") and a not in ("--",)]
        known = set(self._options_for(argv))
        unknown = [f for f in flags if f not in known and f in message]
        if not unknown:
            return None
        flag = unknown[0]
        close = difflib.get_close_matches(flag, sorted(known), n=1, cutoff=0.7)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        return f"unknown option {flag!r}{hint}"

    def _check_value(self, action: argparse.Action, value: Any) -> None:
        choices = action.choices
        if choices is None or value in choices:
            return
        import difflib

        names = [str(c) for c in choices]
        close = difflib.get_close_matches(str(value), names, n=1, cutoff=0.6)
        listed = len(names) <= 12 and not _is_subcommands(action)
        if close:
            hint = f"; did you mean {close[0]!r}?" + (
                f" [one of {', '.join(names)}]" if listed else ""
            )
        else:
            hint = f"; choose from {', '.join(names)}"
        raise argparse.ArgumentError(action, f"unknown {choice_noun(action)} {value!r}{hint}")

    def error(self, message: str) -> NoReturn:
        see = f"see `{self.prog} --help`"
        unknown = self._unknown_options(message)
        if unknown is not None:
            names = [n for n, _ in self._commands(getattr(self, "_argv", []))]
            command = " ".join([self.prog, *names])
            self.exit(EXIT_ERROR, f"error: {unknown} (see `{command} --help`)\n")
        m = _CHOICE.match(message)
        if m:
            message = m[1]
            if m[2]:
                see = f"{m[2]}; {see}"
        self.exit(EXIT_ERROR, f"error: {message} ({see})\n")


def _global_options(parser: argparse.ArgumentParser, *, top: bool) -> None:
    """--quiet and -v; on subcommands they default to SUPPRESS so that a value given
    before the command name is not overwritten."""
    kw: dict[str, Any] = {} if top else {"default": argparse.SUPPRESS}
    parser.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="no progress bars or notes (warnings and errors are still printed)",
        **({"default": False} if top else kw),
    )
    parser.add_argument(
        "-v",
        "--verbose",
        action="count",
        help="show diagnostics (-v: what is done, and every contract check of plugins "
        "--check; -vv: details and tracebacks)",
        **({"default": 0} if top else kw),
    )


#: options the top-level parser takes before a command's name (see :func:`build_parser`)
_TOP_OPTIONS = ("-q", "--quiet", "--verbose")


def _command_of(argv: Sequence[str]) -> str | None:
    """The command named by ``argv`` after the top-level ``-q``/``-v`` options, or None
    (no command, ``--help``, ``--version``, anything else)."""
    for arg in argv:
        if arg in _TOP_OPTIONS or (arg.startswith("-v") and set(arg[1:]) == {"v"}):
            continue
        return None if arg.startswith("-") else arg
    return None


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The argument parser with every registered subcommand.

    Given the command line, the parser holds only the command it names when that
    command's module can be found by name (start-up: importing every command module and
    building every parser is a tenth of a short ``run``); usage errors and help of that
    command read the same either way. Without it, or for anything else (``--help``, an
    unknown command), every command.
    """
    from .commands import load_all, load_command

    parser = ArgumentParser(
        prog="conformal-control",
        description="Conformal decision theory + CBF safety filters on real pedestrian data.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    _global_options(parser, top=True)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=ArgumentParser)
    wanted = None if argv is None else _command_of(argv)
    table = (load_command(wanted) if wanted is not None else None) or load_all()
    for name, (help_text, add_args, _) in sorted(table.items()):
        p = sub.add_parser(
            name, help=help_text, description=help_text, formatter_class=HelpFormatter
        )
        add_args(p)
        _global_options(p, top=False)
    return parser


def describe_error(exc: BaseException) -> str | None:
    """The one-line message for an expected failure, or None for a bug."""
    from ..core.exceptions import ConformalControlError

    if isinstance(exc, ConformalControlError):
        return str(exc)
    sqlite3 = sys.modules.get("sqlite3")  # not imported: no cache database was opened
    if sqlite3 is not None and isinstance(exc, sqlite3.DatabaseError):
        from ..predictors.cache import cache_dir

        return (
            f"a cache database cannot be read ({exc}); delete the cache folder "
            f"{cache_dir()} (or set CONFORMAL_CONTROL_CACHE) and run again"
        )
    if type(exc).__name__ == "UnidentifiedImageError":  # PIL, an OSError subclass
        return f"an image cannot be read ({exc})"
    if isinstance(exc, OSError) and not isinstance(exc, FileNotFoundError) and exc.filename:
        reason = {
            IsADirectoryError: "is a folder, expected a file",
            NotADirectoryError: "is not a folder (a file stands where a folder is needed)",
            PermissionError: "permission denied",
        }.get(type(exc), exc.strerror or str(exc))
        return f"{exc.filename}: {reason}"
    if isinstance(exc, (ValueError, OSError, ImportError)):
        return str(exc) or type(exc).__name__
    cause = exc.__cause__
    if cause is not None and type(exc).__name__ == "PredictorError":
        # a predictor failed for an expected reason: its context, then the reason
        cause_reason = describe_error(cause)
        if cause_reason is not None:
            return f"{str(exc).partition(': ')[0]}: {cause_reason}"
    return None


def _show_warning(
    message: Warning | str,
    category: type[Warning],
    filename: str,
    lineno: int,
    file: Any = None,
    line: str | None = None,
) -> None:
    """warnings.showwarning for the CLI: one line, ``warning: <message>``."""
    from ..core.exceptions import ConformalControlWarning
    from ..core.progress import write

    text = " ".join(str(message).split())
    if not issubclass(category, ConformalControlWarning):
        text = f"{category.__name__}: {text}"
    write(f"warning: {text}", file)


#: The log handlers the command line installed (replaced when it configures logging again).
_CLI_HANDLERS: weakref.WeakSet[logging.Handler] = weakref.WeakSet()


def _configure_logging(verbose: int) -> None:
    logger = logging.getLogger("conformal_control")
    for h in list(logger.handlers):
        if h in _CLI_HANDLERS:
            logger.removeHandler(h)
    if verbose <= 0:
        logger.setLevel(logging.WARNING)
        return
    handler = logging.StreamHandler(sys.stderr)
    _CLI_HANDLERS.add(handler)
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    logger.addHandler(handler)
    logger.setLevel(logging.INFO if verbose == 1 else logging.DEBUG)
    logger.propagate = False


#: The longest error message printed (characters): a value read from a file (a scene
#: name, a cell) may be megabytes long, and a one-line error stays a line.
MAX_ERROR_CHARS = 2000


def _cut(text: str) -> str:
    if len(text) <= MAX_ERROR_CHARS:
        return text
    return f"{text[:MAX_ERROR_CHARS]}... ({len(text) - MAX_ERROR_CHARS} characters cut)"


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``conformal-control`` script."""
    from ..core import progress
    from ..core.exceptions import ConformalControlWarning
    from .commands import COMMANDS

    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(argv)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, usage errors (already printed)
        return exc.code if isinstance(exc.code, int) else EXIT_ERROR
    args.argv = argv
    if args.command is None:
        parser.print_help()
        return 0
    verbose = int(getattr(args, "verbose", 0) or 0)
    _configure_logging(verbose)
    progress.set_quiet(bool(args.quiet))
    old_show = warnings.showwarning
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("default", ConformalControlWarning)
            # our deprecations (a former keyword in --family-param, a 0.2 role name) are
            # the user's to see; other packages' are not
            warnings.filterwarnings(
                "default", category=DeprecationWarning, module=r"conformal_control(\.|$)"
            )
            warnings.showwarning = _show_warning
            return COMMANDS[args.command][2](args)
    except KeyboardInterrupt as exc:
        # a sweep's (bench run, bench tune, reproduce ...): the signal, what its folder
        # holds and how to resume; the exit status 128 + the signal, as a shell reports it
        signum = getattr(exc, "signum", None)
        recorded = getattr(exc, "recorded", None)
        said = str(exc) or "interrupted"
        print(f"error: {said}" + (f": {recorded}" if recorded else ""), file=sys.stderr)
        return 128 + signum if isinstance(signum, int) else EXIT_INTERRUPTED
    except BrokenPipeError:
        # the reader went away (``conformal-control scenes | head``): what it read is all
        # it wanted; silence the flush at exit instead of printing an error
        import os

        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 0
    except Exception as exc:
        message = describe_error(exc)
        if verbose >= 2 or (message is None and verbose >= 1):
            import traceback

            traceback.print_exc()
        if message is None:
            print(
                f"error: internal error ({type(exc).__name__}: {_cut(str(exc))}); this is a "
                "bug, please report it with the command line (rerun with -v to see the "
                "traceback)",
                file=sys.stderr,
            )
            return EXIT_BUG
        print(f"error: {_cut(' '.join(message.split()))}", file=sys.stderr)
        return EXIT_ERROR
    finally:
        warnings.showwarning = old_show
        progress.set_quiet(None)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
