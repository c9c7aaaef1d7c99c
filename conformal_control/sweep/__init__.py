"""Sweeps: run the controller over any parameter grid, locally or on a Dask cluster.

>>> from conformal_control.sweep import SweepSpec, run_sweep
>>> spec = SweepSpec(base={"scene": "crossing", "frames": 100},
...                  grid={"epsilon": [-0.1, 0.1], "seed": [0, 1]})
>>> report = run_sweep(spec, "sweeps/demo", executor="serial")  # doctest: +SKIP

Each finished run is written as it completes (a run directory plus one line of
``results.jsonl``; ``results.csv``/``.parquet`` are rebuilt from it), a rerun skips the keys
already done, and a failing run is recorded with its error and traceback without stopping
the others. See ``docs/sweeps.md``.
"""

from __future__ import annotations

from .executors import EXECUTORS, Executor, ProcessExecutor, SerialExecutor, make_executor
from .results import ResultsStore, flatten_record
from .runner import SweepReport, run_sweep
from .spec import RunConfig, SweepSpec, load_spec, parse_grid_option, run_key
from .worker import METRIC_COLUMNS, execute_run

__all__ = [
    "EXECUTORS",
    "METRIC_COLUMNS",
    "Executor",
    "ProcessExecutor",
    "ResultsStore",
    "RunConfig",
    "SerialExecutor",
    "SweepReport",
    "SweepSpec",
    "execute_run",
    "flatten_record",
    "load_spec",
    "make_executor",
    "parse_grid_option",
    "run_key",
    "run_sweep",
]
