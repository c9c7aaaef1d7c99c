"""``benchmarks/house.py --path``: the command line's ``run`` stays a short path.

The figures are counts of modules and calls (``sys.setprofile``), never timings: the run
from the command line's arguments to the first update of lambda enters at most 12 files and
climbs back to a higher layer at most 15 times (issue 33; 28 files and 55 returns before the
batch engine was split and the front door's work gathered into single calls, 13 and 7 while
``run_episode`` stood between the front door and the engine's choice).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _house():
    spec = importlib.util.spec_from_file_location("_house", ROOT / "benchmarks" / "house.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_run_path_enters_few_files_and_rarely_climbs_back(tmp_path):
    argv = ["run", "--scene", "crossing", "--frames", "40", "--no-plot", "--out"]
    got = _house().follow([*argv, str(tmp_path / "run"), "-q"])
    spine = got["path (modules on the stack at the update)"]
    assert spine[0] == "conformal_control.cli" and spine[-1].endswith("update_rules.base")
    assert "conformal_control.api" in spine  # the command calls the API
    # ... which calls the engine's choice (run_single) itself: no pass-through between
    after_api = spine[spine.index("conformal_control.api") + 1]
    assert after_api.startswith("conformal_control.runs.engines."), spine
    assert got["files entered"] <= 12, got["_detail"]["entered"]
    assert got["returns to a higher layer"] <= 15, got["_detail"]["returns"]
