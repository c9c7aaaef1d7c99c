"""Run directories to export: one robot (the built-in scene) and three robots."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest


@pytest.fixture(scope="package")
def single_run(tmp_path_factory) -> Path:
    import conformal_control as cc

    res = cc.run("crossing", epsilon=-0.1, eta=0.5, seed=0, max_frames=60)
    return Path(res.save(tmp_path_factory.mktemp("single") / "run", plot=False))


@pytest.fixture(scope="package")
def multi_run(tmp_path_factory) -> Path:
    from conformal_control.data import load_scene
    from conformal_control.runs.fleet import run_multi, write_multi_run_dir

    res = run_multi(load_scene("crossing", seed=0), 3, max_frames=50)
    return write_multi_run_dir(res, tmp_path_factory.mktemp("multi") / "run")


def _read_csv(path: Path) -> list[dict[str, float | None]]:
    with path.open(newline="") as fh:
        return [
            {k: (float(v) if v else None) for k, v in row.items()} for row in csv.DictReader(fh)
        ]


@pytest.fixture
def read_csv():
    """The rows of a run directory's CSV file, every cell a float (None when empty), parsed
    independently of the exporter."""
    return _read_csv
