"""Progress feedback for anything that can take more than a couple of seconds.

One helper, :func:`progress`, used by episodes (frames), darts fits, training epochs,
predictor evaluation, sweeps and the benchmark (runs). On a terminal it is a :mod:`tqdm`
bar; when stderr is not a terminal (a log file, CI, a notebook's captured output) it prints
plain lines instead, because tqdm's carriage-return updates turn into one unreadable line
there: the first line once the work has taken ``delay`` seconds, then one every ``every``
seconds (with the time left at the pace so far), and a last line when it ends. Work that
finishes within ``delay`` prints nothing in either mode.

:func:`note` prints a one-line message about what is happening (e.g. which data a
predictor is being trained on). Both are silenced by :func:`set_quiet` (the CLI's
``--quiet``) or ``CONFORMAL_CONTROL_QUIET=1``; ``CONFORMAL_CONTROL_PROGRESS=bar|lines|off``
forces a mode. Warnings are not affected (see :mod:`conformal_control.core.exceptions`).
"""

from __future__ import annotations

import logging
import os
import sys
import time
from collections.abc import Collection, Iterator
from types import TracebackType
from typing import Any, TextIO, TypeVar

__all__ = ["Progress", "is_quiet", "note", "progress", "set_quiet", "track", "write"]

T = TypeVar("T")

logger = logging.getLogger("conformal_control")

_quiet: bool | None = None
#: seconds before a report shows, and between two plain lines (tests set them to 0)
DELAY = 1.0
EVERY = 10.0


def set_quiet(flag: bool | None) -> None:
    """Silence (True) or allow (False) progress and notes; None goes back to the
    ``CONFORMAL_CONTROL_QUIET`` environment variable."""
    global _quiet
    _quiet = flag


def is_quiet() -> bool:
    """Whether progress and notes are silenced."""
    if _quiet is not None:
        return _quiet
    return os.environ.get("CONFORMAL_CONTROL_QUIET", "").strip().lower() in ("1", "true", "yes")


def _mode(stream: TextIO) -> str:
    if is_quiet():
        return "off"
    forced = os.environ.get("CONFORMAL_CONTROL_PROGRESS", "").strip().lower()
    if forced in ("bar", "lines", "off"):
        return forced
    try:
        tty = stream.isatty()
    except (AttributeError, ValueError):
        tty = False
    return "bar" if tty else "lines"


_bars: list[Any] = []  # tqdm bars on screen (a line written meanwhile goes above them)


def write(line: str, file: TextIO | None = None) -> None:
    """Print one line to stderr without breaking a progress bar that is on screen."""
    stream = file if file is not None else sys.stderr
    # bars still within their delay are not on screen: refreshing them would show them
    shown = [b for b in _bars if getattr(b, "last_print_t", 0.0) >= b.start_t + b.delay]
    for b in shown:
        b.clear()
    print(line, file=stream, flush=True)
    for b in shown:
        b.refresh()


def note(message: str) -> None:
    """One line on stderr about what is happening (silenced by quiet; always logged)."""
    logger.info(message)
    if not is_quiet():
        write(message)


class Progress:
    """A progress report; use :func:`progress` to make one.

    ``update(n)`` advances it, ``set_postfix(text)`` sets a short status shown after the
    counts (e.g. the current lambda), ``close()`` (or leaving the ``with`` block) ends it.

    Parameters
    ----------
    total : float or None
        Units of the whole work (None if unknown).
    desc : str
        What is progressing.
    unit : str
        What is counted, plural.
    delay : float, optional
        Seconds before anything is shown; default :data:`DELAY`.
    every : float, optional
        Seconds between two plain lines when the stream is not a terminal; default
        :data:`EVERY`.
    leave : bool
        Keep the finished bar on screen (terminal mode).
    stream : TextIO, optional
        Where the report goes (default ``sys.stderr``).
    initial : float
        Units already done (a resumed sweep); the time left is estimated from the units
        done since.
    """

    def __init__(
        self,
        total: float | None,
        desc: str,
        unit: str = "items",
        *,
        delay: float | None = None,
        every: float | None = None,
        leave: bool = False,
        stream: TextIO | None = None,
        initial: float = 0,
    ) -> None:
        self.total = total
        self.desc = desc
        self.unit = unit
        self.delay = DELAY if delay is None else delay
        self.every = EVERY if every is None else every
        self.n = float(initial)
        self.initial = float(initial)
        self.postfix = ""
        self._stream = stream if stream is not None else sys.stderr
        self._mode = _mode(self._stream)
        self._t0 = time.monotonic()
        self._last_line: float | None = None
        self._closed = False
        self._bar: Any = None
        if self._mode == "bar":
            from tqdm import tqdm

            self._bar = tqdm(
                total=total,
                desc=desc,
                unit=unit,
                delay=self.delay,
                leave=leave,
                file=self._stream,
                dynamic_ncols=True,
                initial=initial,
            )
            _bars.append(self._bar)

    # ---------------------------------------------------------------- reporting
    @property
    def elapsed(self) -> float:
        return time.monotonic() - self._t0

    def _line(self, final: bool = False) -> str:
        tail = f", {self.postfix}" if self.postfix else ""
        if final:  # the work may end early (a goal reached before the data ran out)
            return f"{self.desc}: done, {self.n:.0f} {self.unit} in {self.elapsed:.1f} s{tail}"
        count = f"{self.n:.0f}" if self.total is None else f"{self.n:.0f}/{self.total:.0f}"
        pct = f" ({100.0 * self.n / self.total:.0f}%)" if self.total else ""
        return f"{self.desc}: {count} {self.unit}{pct}, {self.elapsed:.1f} s{self._left()}{tail}"

    def _left(self) -> str:
        """``, about N s left`` from the pace so far (nothing before a unit is done)."""
        done = self.n - self.initial
        if not self.total or done <= 0 or self.n >= self.total:
            return ""
        left = self.elapsed / done * (self.total - self.n)
        return f", about {left:.0f} s left" if left < 90 else f", about {left / 60:.0f} min left"

    def _maybe_print(self) -> None:
        now = time.monotonic()
        if now - self._t0 < self.delay:
            return
        if self._last_line is not None and now - self._last_line < self.every:
            return
        self._last_line = now
        print(self._line(), file=self._stream, flush=True)

    def update(self, n: float = 1) -> None:
        """Advance by ``n`` units."""
        self.n += n
        if self._bar is not None:
            self._bar.update(n)
        elif self._mode == "lines":
            self._maybe_print()

    def set_postfix(self, text: str) -> None:
        """A short status shown after the counts."""
        self.postfix = text
        if self._bar is not None:
            self._bar.set_postfix_str(text, refresh=False)

    def close(self) -> None:
        """End the report (a last line in line mode if anything was printed)."""
        if self._closed:
            return
        self._closed = True
        if self._bar is not None:
            self._bar.close()
            if self._bar in _bars:
                _bars.remove(self._bar)
        elif self._mode == "lines" and self._last_line is not None:
            print(self._line(final=True), file=self._stream, flush=True)

    def __enter__(self) -> Progress:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def progress(
    total: float | None,
    desc: str,
    unit: str = "items",
    *,
    delay: float | None = None,
    every: float | None = None,
    leave: bool = False,
    initial: float = 0,
) -> Progress:
    """A progress report over ``total`` units (None if unknown).

    Parameters
    ----------
    total : float or None
    desc : str
        What is progressing (``"run nexus_4"``, ``"darts fits"``, ...).
    unit : str
        What is counted, plural (``"frames"``, ``"fits"``, ``"epochs"``).
    delay : float, optional
        Seconds before anything is shown (short work stays silent); default :data:`DELAY`.
    every : float, optional
        Seconds between two plain lines when stderr is not a terminal; default
        :data:`EVERY`.
    leave : bool
        Keep the finished bar on screen (terminal mode).
    initial : float
        Units already done (a resumed sweep).
    """
    return Progress(total, desc, unit, delay=delay, every=every, leave=leave, initial=initial)


def track(
    items: Collection[T], desc: str, unit: str = "items", *, enabled: bool = True
) -> Iterator[T]:
    """Iterate over ``items`` with a :func:`progress` report (a bar on a terminal, plain
    lines in a log file).

    Parameters
    ----------
    items : Collection
        What is iterated over (its length is the report's total).
    desc : str
        What is progressing.
    unit : str
        What is counted, plural.
    enabled : bool
        False: no report, the items only.
    """
    if not enabled:
        yield from items
        return
    with progress(len(items), desc, unit) as bar:
        for item in items:
            yield item
            bar.update()
