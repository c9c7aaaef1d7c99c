"""Starts and goals as users type them: fractions of the scene's frame, metres, pixels."""

from __future__ import annotations

import numpy as np
import pytest

from conformal_control.core.exceptions import InputError
from conformal_control.data.positions import (
    Position,
    parse_position,
    parse_positions,
    to_metres,
)


@pytest.mark.parametrize(
    ("typed", "expected"),
    [
        ("0.05,0.5", Position(0.05, 0.5)),
        ((0.05, 0.5), Position(0.05, 0.5)),
        ("3.2m,1.0m", Position(3.2, 1.0, "m")),
        (" 3.2 m , -1e1m", Position(3.2, -10.0, "m")),
        (("3.2m", "1m"), Position(3.2, 1.0, "m")),
        ("120px,300px", Position(120.0, 300.0, "px")),
        (np.array([0.0, 1.0]), Position(0.0, 1.0)),
    ],
)
def test_the_forms_a_position_takes(typed: object, expected: Position) -> None:
    assert parse_position(typed) == expected
    assert parse_position(str(expected)) == expected  # printed as it is typed


@pytest.mark.parametrize(
    ("typed", "words"),
    [
        ("0.1", "two numbers fx,fy"),
        ("1,2,3", "two numbers fx,fy"),
        ("1m,2", "same unit"),
        ("1.5,0.5", "write 1.5m,0.5m for metres"),
        ("3ft,1ft", "'3ft' is not a number"),
        ("nan,1", "'nan' is not a number"),
        ((float("inf"), 0.5), "must be finite"),
        (5, "two numbers fx,fy"),
    ],
)
def test_a_bad_position_is_one_clear_line(typed: object, words: str) -> None:
    with pytest.raises(InputError) as err:
        parse_position(typed, "--start")
    assert words in str(err.value) and "\n" not in str(err.value)


def test_one_goal_or_a_list_of_them() -> None:
    assert parse_positions((0.9, 0.5)) == [Position(0.9, 0.5)]
    assert parse_positions("9m,5m") == [Position(9.0, 5.0, "m")]
    assert parse_positions([(0.9, 0.5), "9m,5m"]) == [Position(0.9, 0.5), Position(9, 5, "m")]
    with pytest.raises(InputError, match="goal 2"):
        parse_positions([(0.9, 0.5), "x"], "goal")


def test_metres_from_each_unit() -> None:
    frame = (np.array([-2.0, 1.0]), np.array([10.0, 4.0]))
    f = to_metres(Position(0.5, 0.25), frame=frame, m_per_px=None, scene="s")
    np.testing.assert_allclose(f, [3.0, 2.0])
    m = to_metres(Position(3.0, 2.0, "m"), frame=None, m_per_px=None, scene="s")
    np.testing.assert_allclose(m, [3.0, 2.0])
    px = to_metres(Position(100, 50, "px"), frame=None, m_per_px=0.04, scene="s")
    np.testing.assert_allclose(px, [4.0, 2.0])
    with pytest.raises(InputError, match="scene s has no image"):
        to_metres(Position(1, 1, "px"), frame=frame, m_per_px=None, scene="s")
    with pytest.raises(InputError, match="scene s has no frame for fractions"):
        to_metres(Position(0.5, 0.5), frame=None, m_per_px=None, scene="s")
