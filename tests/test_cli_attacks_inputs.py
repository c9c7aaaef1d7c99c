"""Smaller attacks on what a user types or a file holds (issue 32, item 9): no error echoes
a file that is not what it should be, every value read from a file is checked where it is
read, and the data folder is named by where it really came from."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import pytest

from conformal_control.cli import EXIT_ERROR, main


def _replay(tmp_path: Path, cli: dict) -> int:
    (tmp_path / "config.json").write_text(json.dumps({"cli": cli}))
    return main(["run", "--config", str(tmp_path), "--out", str(tmp_path / "r"), "--no-plot"])


def test_a_replayed_config_naming_a_secret_file_does_not_print_it(
    tmp_path: Path, error_line
) -> None:
    secret = tmp_path / "shadow"
    secret.write_text("root:$6$SECRETHASH:19000:0:99999:7:::\nfoo,bar,baz\n")
    cli = {"scene": "crossing", "frames": 5, "predictor": "recorded"}
    cli["predictor_param"] = [f"path={secret}"]
    assert _replay(tmp_path, cli) == EXIT_ERROR
    line = error_line()
    assert "missing column(s)" in line and "SECRETHASH" not in line and "foo" not in line


def test_a_huge_name_read_from_a_file_is_cut(tmp_path: Path, error_line) -> None:
    assert _replay(tmp_path, {"scene": "x" * (10 << 20), "frames": 5}) == EXIT_ERROR
    line = error_line()
    assert "unknown scene 'xxx" in line and len(line) < 1000


def test_a_binary_config_is_named(tmp_path: Path, error_line) -> None:
    (tmp_path / "c.json").write_bytes(b"\xff\xfe\x00\x01garbage\x89PNG")
    assert main(["run", "--config", str(tmp_path / "c.json")]) == EXIT_ERROR
    line = error_line()
    assert str(tmp_path / "c.json") in line and "not a text file" in line


@pytest.mark.parametrize(
    ("param", "words"),
    [
        ("lambda_max=-inf", "parameter lambda_max must be finite or the open end (inf)"),
        ("lambda_min=inf", "parameter lambda_min must be finite or the open end (-inf)"),
        ("lambda_init=inf", "parameter lambda_init must be finite"),
    ],
)
def test_an_empty_lambda_range_is_blamed_on_the_parameter(
    param: str, words: str, tmp_path: Path, error_line
) -> None:
    """It used to be blamed on the predictions ("predictions must be sanitised")."""
    argv = ["run", "--scene", "crossing", "--frames", "5", "--param", param]
    assert main([*argv, "--out", str(tmp_path / "r")]) == EXIT_ERROR
    assert words in error_line()


def test_a_data_root_on_a_link_loop_names_where_it_came_from(
    tmp_path: Path, monkeypatch, error_line
) -> None:
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    monkeypatch.setenv("CONFORMAL_CONTROL_DATA", str(tmp_path / "a"))
    argv = ["run", "--scene", "nexus_4", "--frames", "5", "--out", str(tmp_path / "r")]
    assert main(argv) == EXIT_ERROR
    line = error_line()
    assert "($CONFORMAL_CONTROL_DATA) is a loop of symbolic links" in line
    assert "--data-root" not in line.split("links")[0]


def test_an_empty_data_root_is_not_the_current_folder(tmp_path: Path, error_line) -> None:
    argv = ["run", "--scene", "nexus_4", "--frames", "5", "--data-root", ""]
    assert main([*argv, "--out", str(tmp_path / "r")]) == EXIT_ERROR
    assert "--data-root is empty" in error_line()


@pytest.mark.parametrize("value", [1e300, "1", True, None])
def test_robots_file_coordinates_are_json_numbers_of_a_plausible_size(
    value: object, tmp_path: Path, error_line
) -> None:
    robots = [{"start": [2.0, 8.0], "goal": [28.0, 8.0]}, {"start": [value, 2.0], "goal": [20, 20]}]
    (tmp_path / "robots.json").write_text(json.dumps({"robots": robots}))
    argv = ["run", "--scene", "crossing", "--frames", "5", "--no-plot"]
    argv += ["--robots-file", str(tmp_path / "robots.json"), "--out", str(tmp_path / "r")]
    assert main(argv) == EXIT_ERROR
    line = error_line()
    assert "robot 1 has a start or goal that is not two numbers [x, y] within 1e+06" in line


def test_recorded_ids_beyond_2_to_the_53_are_refused(tmp_path: Path, error_line) -> None:
    """A frame of 1e19 wrapped to a negative int64 with only a RuntimeWarning."""
    f = tmp_path / "p.csv"
    f.write_text("frame,track_id,step,x,y\n10000000000000000000,1,1,0,0\n")
    argv = ["run", "--scene", "crossing", "--frames", "5", "--predictor", "recorded"]
    argv += ["--predictor-param", f"path={f}", "--out", str(tmp_path / "r")]
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # the silent wrap of before
        assert main(argv) == EXIT_ERROR
    assert "frame and track_id must lie within +-2^53" in error_line()


def test_a_nan_parameter_in_a_replayed_spec_is_an_input_error() -> None:
    from conformal_control.core.exceptions import InputError
    from conformal_control.core.spec import RunSpec

    with pytest.raises(InputError, match="parameter epsilon must be finite, got nan"):
        RunSpec.from_dict({"params": {"epsilon": math.nan}}, where="config.json")
