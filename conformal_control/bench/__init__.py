"""Closed-loop safety benchmark on real crowds: scenario suites (and, later, methods).

:mod:`~conformal_control.bench.suites` loads the shipped suites and builds a scenario's
scene; :mod:`~conformal_control.bench.generator` regenerates them from the data.
"""

from .suites import (
    SPLITS,
    Scenario,
    Suite,
    dump_manifest,
    load_scenario,
    load_suite,
    suite_names,
    validate_manifest,
)

__all__ = [
    "SPLITS",
    "Scenario",
    "Suite",
    "dump_manifest",
    "load_scenario",
    "load_suite",
    "suite_names",
    "validate_manifest",
]
