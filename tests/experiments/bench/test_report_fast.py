"""The report's row helpers take shortcuts that change no number: a float is its own value
in ``_num``, and a prepared row is not prepared (copied) again -- preparing is idempotent,
which the shortcut relies on."""

from __future__ import annotations

import math

import numpy as np

from conformal_control.experiments.bench import report


def _num_before(v: object) -> float:
    """``_num`` before the float shortcut."""
    if v is None or v == "":
        return math.nan
    if isinstance(v, str):
        low = v.strip().lower()
        if low in ("true", "false"):
            return 1.0 if low == "true" else 0.0
        try:
            return float(v)
        except ValueError:
            return math.nan
    return float(v)  # type: ignore[arg-type]


def test_num_gives_the_former_numbers() -> None:
    values = [0.0, -0.0, 1.5, math.inf, -math.inf, math.nan, 3, True, False, None, "",
              " TRUE ", "false", "2.5", "x", np.float64(0.25), np.int64(4)]  # fmt: skip
    for v in values:
        got, want = report._num(v), _num_before(v)
        assert type(got) is float or isinstance(got, float)
        assert np.float64(got).tobytes() == np.float64(want).tobytes(), v


def test_a_prepared_row_is_used_as_it_is_and_preparing_is_idempotent() -> None:
    rows = [
        {"goal_reached": True, "t_goal": 12.5, "time_limit": 40.0, "lambda_mean": 0.2,
         "lambda_unit_si": 2.5, "shift": None, "method": "m", "scenario": "s"},
        {"goal_reached": "false", "t_goal": "", "time_limit": 40, "lambda_mean": None,
         "shift": "delay-0.5s", "method": "m", "scenario": "s"},
    ]  # fmt: skip
    for row in rows:
        once = report._prepared(row)
        assert once is not row and "t_goal_or_limit" in once
        assert report._prepared(once) is once  # not copied again
        again = dict(report._prepared(dict(once)))  # a plain copy is prepared anew
        assert list(again) == list(once)
        for k in once:
            assert np.asarray(again[k]).tobytes() == np.asarray(once[k]).tobytes(), k
