"""The project's warning classes and user-facing error classes.

Warnings are raised with :func:`warnings.warn` and are all subclasses of
:class:`ConformalControlWarning`, so a script can silence or escalate them as a group::

    import warnings
    from conformal_control.core.exceptions import ConformalControlWarning

    warnings.simplefilter("error", ConformalControlWarning)   # make every one an error

``conformal-control`` prints each as one line, ``warning: <message>``. A warning says that
the run that happens is probably not the one that was meant (an unattainable target, a run
in which lambda never moved, a value that looks typed in the wrong unit, an option that is
ignored); what merely describes a run goes to the ``conformal_control`` logger (``-v``).

Errors for expected failures (bad input, bad data, an unwritable output) are subclasses of
:class:`ConformalControlError` *and* of the builtin class a caller would catch anyway
(``ValueError``, ``OSError``), so existing ``except ValueError`` code keeps working. Their
message is one sentence that names the offending input and says what to do.

This module imports nothing from the package: every layer may use it.
"""

from __future__ import annotations

__all__ = [
    "CacheWarning",
    "ConformalControlDeprecationWarning",
    "ConformalControlError",
    "ConformalControlWarning",
    "DataFetchError",
    "DataFormatError",
    "FeasibilityWarning",
    "GoalNotReachedWarning",
    "IgnoredOptionWarning",
    "InputError",
    "LambdaOverflowError",
    "NoUpdatesWarning",
    "OptionConflictWarning",
    "OutputNotWritableError",
    "SuspiciousValueWarning",
]


# ------------------------------------------------------------------------------ warnings
class ConformalControlWarning(UserWarning):
    """Base class of every warning the project emits."""


class ConformalControlDeprecationWarning(DeprecationWarning):
    """A way of an earlier version that still works (a renamed keyword, role or option),
    with its replacement and the version it goes in. A :class:`DeprecationWarning`, so
    every filter of those applies; its own class lets a test suite turn the project's
    deprecations (and no other package's) into errors."""


class FeasibilityWarning(ConformalControlWarning):
    """The target average loss epsilon is at or below the feasibility floor s(-a h_max):
    no lambda makes every sensed agent's constraint feasible at that loss level."""


class NoUpdatesWarning(ConformalControlWarning):
    """A learning run ended without a single lambda update (nothing was ever sensed)."""


class GoalNotReachedWarning(ConformalControlWarning):
    """The episode ended before the last goal was reached because the recorded data ran
    out (a run stopped by the ``max_frames`` / ``--frames`` limit the caller set is only
    logged).

    Attributes
    ----------
    reason : str
        ``"data_ended"``.
    """

    def __init__(self, message: str, reason: str = "data_ended") -> None:
        super().__init__(message)
        self.reason = reason


class OptionConflictWarning(ConformalControlWarning):
    """One setting was given twice with different values; the message says which one won."""


class IgnoredOptionWarning(ConformalControlWarning):
    """An option was given that has no effect on this run (the message says why)."""


class CacheWarning(ConformalControlWarning):
    """A cache entry (trained weights, compiled code) was unreadable, failed its checksum
    or could not be written; it was set aside and the work is redone (the message names
    the path)."""


class SuspiciousValueWarning(ConformalControlWarning):
    """A parameter value is implausible in the unit it was read in (e.g. a length typed in
    pixels that is under a metre); the message suggests the explicit unit suffix."""


class TunedOnReportedSplitWarning(ConformalControlWarning):
    """A benchmark reports figures on the split its tuned values were chosen on (``bench
    tune --split test`` then ``bench run --split test``): the tuned methods are not held
    out there."""


# ------------------------------------------------------------------------------ errors
class ConformalControlError(Exception):
    """Base class of the project's user-facing errors (one-sentence messages)."""


class InputError(ConformalControlError, ValueError):
    """A parameter, option or argument is invalid."""


class DataFormatError(ConformalControlError, ValueError):
    """A data file is malformed; the message gives ``file:line`` and what is wrong."""


class LambdaOverflowError(ConformalControlError, ValueError):
    """lambda left the floating-point range during a run (learning rate far too large)."""


class OutputNotWritableError(ConformalControlError, OSError):
    """The output location cannot be written (checked before any work is done)."""


class DataFetchError(ConformalControlError, OSError):
    """A data file could not be downloaded (offline, unreachable host, HTTP error)."""
