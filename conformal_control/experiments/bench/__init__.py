"""Closed-loop safety benchmark on real crowds.

Scenario suites (:mod:`conformal_control.data.suites`: the shipped manifests and a
scenario's scene; :mod:`~conformal_control.experiments.bench.generator` regenerates them from the
data), methods declared as data (:mod:`~conformal_control.experiments.bench.methods`), predictor
shifts
(:mod:`~conformal_control.experiments.bench.shifts`), the tuning protocol
(:mod:`~conformal_control.experiments.bench.tune`), the runner
(:mod:`~conformal_control.experiments.bench.suite`),
statistics (:mod:`~conformal_control.experiments.bench.stats`) and reports
(:mod:`~conformal_control.experiments.bench.report`). Collisions are classified in every run's
metrics
(:mod:`conformal_control.runs.results.collisions`).
"""

from ...data.suites import (
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
