"""One accepted name per recording: the aliases (the literature's split names, fetch-data's
``sdd:<scene>_<N>``) are resolved by the data catalog, and every command that names a
recording or a data set takes the same names."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from conformal_control.cli import EXIT_ERROR, main
from conformal_control.core.exceptions import InputError
from conformal_control.data import load_scene
from conformal_control.data.catalog import (
    dataset_name,
    ethucy_split,
    fetch_selector,
    scene_name,
    suggest_scene,
)
from conformal_control.data.ethucy import ETHUCY_RECORDINGS
from conformal_control.data.fetch import plan


@pytest.mark.parametrize(
    ("given", "scene", "dataset", "fetched"),
    [
        ("ethucy:zara1", "ethucy:crowds_zara01", "ethucy:zara1", "ethucy:zara1"),
        ("ethucy:crowds_zara01", "ethucy:crowds_zara01", "ethucy:zara1", "ethucy:zara1"),
        ("ethucy:eth:corrected", "ethucy:biwi_eth:corrected", "ethucy:eth", "ethucy:eth"),
        ("ethucy:biwi_hotel", "ethucy:biwi_hotel", "ethucy:hotel", "ethucy:hotel"),
        ("sdd:nexus_4", "sdd:nexus/video4", "nexus_4", "sdd:nexus_4"),
        ("sdd:quad_2", "sdd:quad/video2", "sdd:quad/video2", "sdd:quad_2"),
        ("sdd:quad/video2", "sdd:quad/video2", "sdd:quad/video2", "sdd:quad_2"),
    ],
)
def test_every_alias_resolves_to_the_one_name(
    given: str, scene: str, dataset: str, fetched: str
) -> None:
    assert scene_name(given) == scene
    assert dataset_name(given) == dataset
    assert fetch_selector(given) == fetched


def test_each_ethucy_recording_has_one_name_and_its_split() -> None:
    for rec, split in ETHUCY_RECORDINGS.items():
        assert scene_name(f"ethucy:{rec}") == f"ethucy:{rec}"
        assert ethucy_split(rec) == split
    with pytest.raises(InputError, match=r"ethucy:students001 or ethucy:students003"):
        scene_name("ethucy:univ")
    with pytest.raises(InputError, match=r"use ethucy:univ"):
        dataset_name("ethucy:students003")
    with pytest.raises(InputError, match=r"did you mean 'ethucy:crowds_zara01'"):
        scene_name("ethucy:zarra1")


@pytest.mark.parametrize(
    ("typed", "suggested"),
    [
        ("zara1", "ethucy:crowds_zara01"),
        ("crowds_zara02", "ethucy:crowds_zara02"),
        ("univ", "ethucy:students001"),
        ("nexus/video3", "sdd:nexus/video3"),
        ("quad_2", "sdd:quad/video2"),
    ],
)
def test_a_name_without_its_prefix_suggests_the_full_one(
    typed: str, suggested: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert suggest_scene(typed) == suggested
    assert main(["run", "--scene", typed, "-q"]) == EXIT_ERROR
    err = capsys.readouterr().err.strip()
    assert err == (
        f"error: unknown scene {typed!r}; did you mean {suggested!r}? (see `conformal-control "
        "scenes`)"
    )


def test_a_typo_of_a_registered_scene_still_suggests_it() -> None:
    assert suggest_scene("nexus_4") is not None  # the pattern of an SDD video...
    with pytest.raises(InputError, match=r"did you mean 'nexus_4'\?"):
        load_scene("nexsu_4")  # ...but the registered name is closer


def test_the_commands_take_the_same_names(
    data_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """run, eval-predictor and fetch-data read ethucy:zara1 and ethucy:crowds_zara01 as the
    same recording (the issue: run refused the short form the others took)."""
    for name in ("ethucy:zara1", "ethucy:crowds_zara01"):
        out = tmp_path / name.replace(":", "_")
        argv = ["run", "--scene", name, "--data-root", str(data_root), "--frames", "30"]
        assert main([*argv, "-q", "--no-plot", "--out", str(out)]) == 0
        capsys.readouterr()
        assert json.loads((out / "config.json").read_text())["scene"]["name"] == "crowds_zara01"
        argv = ["eval-predictor", "--predictor", "constant_velocity", "--dataset", name]
        assert main([*argv, "--data-root", str(data_root), "-q"]) == 0
        assert capsys.readouterr().out.startswith("constant_velocity ethucy:zara1: ADE 0.516")
    assert [p.path for p in plan(["ethucy:crowds_zara01"])] == [
        p.path for p in plan(["ethucy:zara1"])
    ]
    assert [p.path for p in plan(["sdd:nexus/video4"])] == [p.path for p in plan(["sdd:nexus_4"])]
