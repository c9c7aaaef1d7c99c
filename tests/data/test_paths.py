"""The data root: --data-root, then $CONFORMAL_CONTROL_DATA, then the per-user data folder
(where fetch-data downloads by default); a missing file names all three."""

from __future__ import annotations

from pathlib import Path

import pytest

from conformal_control.cli import main
from conformal_control.data import load_scene
from conformal_control.data.paths import (
    ENV_VAR,
    DataNotFoundError,
    data_root_origin,
    resolve_data_root,
    user_data_dir,
)


@pytest.fixture
def user_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A fresh per-user data folder (platformdirs reads XDG_DATA_HOME on Linux and
    $HOME elsewhere), no $CONFORMAL_CONTROL_DATA."""
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.delenv(ENV_VAR, raising=False)
    return user_data_dir()


def test_the_order_is_argument_then_environment_then_user_folder(
    user_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert user_dir.name == "conformal-control" and tmp_path in user_dir.parents
    assert data_root_origin() == (user_dir, "the per-user data folder")
    assert resolve_data_root() == user_dir
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "env"))
    assert data_root_origin() == (tmp_path / "env", f"${ENV_VAR}")
    assert resolve_data_root(tmp_path / "arg") == tmp_path / "arg"
    assert data_root_origin(tmp_path / "arg")[1] == "--data-root"


@pytest.mark.parametrize("origin", ["user", "env", "arg"])
def test_not_found_names_the_three_places_and_which_one_was_used(
    origin: str, user_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    arg = None
    if origin == "env":
        monkeypatch.setenv(ENV_VAR, str(tmp_path / "env"))
    elif origin == "arg":
        arg = tmp_path / "arg"
    with pytest.raises(DataNotFoundError) as err:
        load_scene("nexus_4", arg)
    msg = str(err.value)
    assert "--data-root DIR" in msg and f"${ENV_VAR}" in msg
    assert f"the per-user data folder {user_dir}" in msg
    assert "`conformal-control fetch-data`" in msg
    used = {
        "user": "the data folder is the per-user data folder",
        "env": f"the data folder is ${ENV_VAR}={tmp_path / 'env'}",
        "arg": "the data folder was given with --data-root",
    }[origin]
    assert used in msg
    assert "\n" not in msg


def test_fetch_data_without_dest_fills_the_user_folder_that_run_then_reads(
    user_dir: Path, data_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["fetch-data", "--only", "sdd:nexus_4", "--mirror", str(data_root), "--quiet"])
    assert code == 0
    out = capsys.readouterr().out
    assert f"in {user_dir};" in out and "every command reads it" in out
    assert (user_dir / "sdd" / "estimated_scales.yaml").is_file()
    # no --data-root, no $CONFORMAL_CONTROL_DATA: the per-user folder is read
    assert load_scene("nexus_4").n_agents == 47
    code = main(
        [
            "run",
            "--scene",
            "nexus_4",
            "--frames",
            "5",
            "--no-plot",
            "--quiet",
            "--out",
            str(tmp_path / "run"),
        ]
    )
    assert code == 0, capsys.readouterr().err


def test_fetch_data_with_dest_says_how_to_use_it(
    user_dir: Path, data_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    dest = tmp_path / "elsewhere"
    assert (
        main(
            [
                "fetch-data",
                "--dest",
                str(dest),
                "--only",
                "sdd:nexus_4",
                "--mirror",
                str(data_root),
                "--quiet",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert f"--data-root {dest} or {ENV_VAR}={dest}" in out
    assert not user_dir.exists()


@pytest.mark.parametrize(
    "part", ["", "sdd", "ethucy", "ethucy/zara1", "ethucy/zara1/test", "sdd/annotations"]
)
def test_the_data_root_may_be_any_part_of_the_data_folder(
    data_root: Path, part: str, tmp_path: Path
) -> None:
    """Given the data folder or any folder of it (the SDD folder, the ETH/UCY folder, a
    split, the annotations), every loader finds its own part: the issue's ETH/UCY commands
    looked for ``sdd/ethucy/zara1/test`` when the root was the SDD folder."""
    from conformal_control.data.paths import data_part, ethucy_root, sdd_root
    from conformal_control.predictors.evaluation import dataset_windows, training_windows

    root = data_root / part
    assert sdd_root(root) == data_root / "sdd"
    assert ethucy_root(root) == data_root / "ethucy"
    assert data_part("external", root) == data_root / "external"
    assert load_scene("ethucy:zara1", root, last_frame=300).n_agents > 0
    assert load_scene("nexus_4", root).name == "nexus_4"
    assert len(dataset_windows("ethucy:hotel", root)) > 0
    assert len(training_windows("nexus_4", root)) > 0
    # an SDD folder of another name is the SDD folder all the same (its own files)
    (tmp_path / "drone").symlink_to(data_root / "sdd")
    assert sdd_root(tmp_path / "drone") == tmp_path / "drone"
