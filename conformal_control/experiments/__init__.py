"""Sweeps: run the controller over any parameter grid, locally or on a Dask cluster.

>>> from conformal_control.experiments import SweepSpec, run_sweep
>>> spec = SweepSpec(base={"scene": "crossing", "frames": 100},
...                  grid={"epsilon": [-0.1, 0.1], "seed": [0, 1]})
>>> report = run_sweep(spec, "sweeps/demo", executor="serial")  # doctest: +SKIP

Every configuration is checked before any run starts; one sweep at a time may write a
folder (``.lock``). Each finished run is written as it completes (a run directory plus one
line of ``results.jsonl``; ``results.csv``/``.parquet`` are rebuilt from it), a rerun skips
the keys already done, and a failing run is recorded with its error and traceback without
stopping the others. See ``docs/sweeps.md``.
"""

from __future__ import annotations

from .executors import EXECUTORS, Executor, ProcessExecutor, SerialExecutor, make_executor
from .lock import SweepLock, SweepLockedError
from .plan import RunConfig, SweepRun, SweepSpec, load_spec, parse_grid_option, run_key
from .results import JournalWarning, ResultsStore, flatten_record
from .runner import SweepInterrupted, SweepReport, run_sweep
from .validate import SweepValidationError, validate_runs
from .worker import METRIC_COLUMNS, execute_run

__all__ = [
    "EXECUTORS",
    "METRIC_COLUMNS",
    "Executor",
    "JournalWarning",
    "ProcessExecutor",
    "ResultsStore",
    "RunConfig",
    "SerialExecutor",
    "SweepInterrupted",
    "SweepLock",
    "SweepLockedError",
    "SweepReport",
    "SweepRun",
    "SweepSpec",
    "SweepValidationError",
    "execute_run",
    "flatten_record",
    "load_spec",
    "make_executor",
    "parse_grid_option",
    "run_key",
    "run_sweep",
    "validate_runs",
]
