"""Scenario suites: the shipped manifest, its split, its regeneration, a scenario's episode."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from conformal_control.cli import main
from conformal_control.data import suites as suites_module
from conformal_control.data.suites import shipped_scenario, suite_names
from conformal_control.experiments.bench import (
    dump_manifest,
    load_scenario,
    load_suite,
    validate_manifest,
)
from conformal_control.experiments.bench.generator import (
    CROSSINGS_V1,
    assign_splits,
    generate_suite,
    manifest_entries,
    regenerate_suite,
)
from conformal_control.runs.episode import run_episode

SDD_RAW_VIDEOS = {
    "deathCircle": (2, 4),
    "gates": (2, 4, 5, 6, 7, 8),
    "hyang": (7, 8, 9, 12, 13, 14),
    "little": (0,),
    "nexus": (3, 4, 5, 10),
    "quad": (0, 1, 2, 3),
}
#: Small recordings regenerated in full (nolearn episodes included) by the tests.
REGENERATED = ["sdd:deathCircle/video2", "sdd:little/video0"]


@pytest.fixture(scope="module")
def suite():
    return load_suite("crossings-v1")


def _video(recording: str) -> str:
    """The video a recording comes from (raw and TrajNet forms of one video are one)."""
    return recording.removesuffix(":trajnet").removesuffix(":raw").replace("sdd:", "")


def test_shipped_suite_is_valid_and_large_enough(suite) -> None:
    assert "crossings-v1" in suite_names()
    m = suite.manifest
    validate_manifest(m)
    assert m["suite"] == "crossings" and m["version"] == 1
    assert len(suite.scenarios) >= 300
    collided = [s for s in suite.scenarios if s.collided_nolearn]
    assert len(collided) >= 100
    # the nolearn baseline is stated: constant velocity, no learning, scene defaults
    assert m["nolearn"]["measured"] and m["nolearn"]["predictor"] == "constant_velocity"
    assert m["nolearn"]["learn"] is False and "a = 10 per frame" in m["nolearn"]["note"]
    # every raw SDD video of the data was processed, every source contributes
    raw = {r["id"] for r in m["recordings"] if r["source"] == "sdd"}
    assert raw == {f"sdd:{sc}/video{v}" for sc, vs in SDD_RAW_VIDEOS.items() for v in vs}
    assert {s.source for s in suite.scenarios} == {"sdd", "trajnet", "ethucy"}
    for rec in m["recordings"]:
        mine = [s for s in suite.scenarios if s.recording == rec["id"]]
        assert rec["n_scenarios"] == len(mine) <= rec["n_windows"]
        assert rec["n_nolearn_collision"] == sum(bool(s.collided_nolearn) for s in mine)
    crit = m["generator"]["criterion"]
    for s in suite.scenarios:
        # the criterion's promises, checked on what was stored
        assert s.stats["n_crossing"] >= crit["min_crossings"]
        length = np.hypot(*(np.subtract(s.goal_m, s.start_m)))
        assert length == pytest.approx(s.length_m, abs=2e-3)
        t_straight = s.length_m / s.v_ref
        assert 2.0 <= s.time_limit_s / t_straight <= 3.0
        assert s.max_frames == round(s.time_limit_s * s.fps)
        if s.source != "ethucy":
            assert s.start_fraction is not None
            assert all(0.0 <= v <= 1.0 for v in (*s.start_fraction, *s.goal_fraction))
        else:
            assert s.start_fraction is None


def test_split_is_by_video_and_follows_the_rule(suite) -> None:
    dev = {_video(s.recording) for s in suite.scenarios_for("dev")}
    test = {_video(s.recording) for s in suite.scenarios_for("test")}
    assert dev and test and not dev & test
    assert len(suite.scenarios_for("dev")) + len(suite.scenarios_for("test")) == len(
        suite.scenarios
    )
    splits = assign_splits(CROSSINGS_V1.recordings)
    assert {r["id"]: r["split"] for r in suite.manifest["recordings"]} == splits
    # alternating within a location: nexus 3, 4, 5, 10 -> test, dev, test, dev
    assert [splits[f"sdd:nexus/video{v}"] for v in (3, 4, 5, 10)] == ["test", "dev"] * 2
    # single-recording locations pooled by id: biwi_eth, biwi_hotel, bookstore, coupa, little
    pooled = ["ethucy:biwi_eth", "ethucy:biwi_hotel", "sdd:bookstore/video0:trajnet"]
    assert [splits[r] for r in pooled] == ["test", "dev", "test"]
    with pytest.raises(ValueError, match="split must be one of"):
        suite.scenarios_for("train")


def test_validate_manifest_names_the_problem(suite) -> None:
    m = copy.deepcopy(suite.manifest)
    m["scenarios"][1]["id"] = m["scenarios"][0]["id"]
    with pytest.raises(ValueError, match="duplicate id"):
        validate_manifest(m)
    m = copy.deepcopy(suite.manifest)
    m["scenarios"][0]["split"] = "test" if m["scenarios"][0]["split"] == "dev" else "dev"
    with pytest.raises(ValueError, match="split differs"):
        validate_manifest(m)
    m = copy.deepcopy(suite.manifest)
    del m["scenarios"][3]["max_frames"]
    with pytest.raises(ValueError, match="missing key 'max_frames'"):
        validate_manifest(m)
    with pytest.raises(ValueError, match="expected schema"):
        validate_manifest({**suite.manifest, "schema_version": 99})
    with pytest.raises(ValueError, match="unknown suite"):
        load_suite("crossings-v9")


def _entries(manifest: dict, recordings: list[str], drop_nolearn: bool = False) -> list[str]:
    recs = [dict(r) for r in manifest["recordings"] if r["id"] in recordings]
    scs = [dict(s) for s in manifest["scenarios"] if s["recording"] in recordings]
    if drop_nolearn:
        for r in recs:
            r.pop("n_nolearn_collision")
        for s in scs:
            s.pop("nolearn")
    return [json.dumps(x, indent=1) for x in (*recs, *scs)]


def test_regeneration_reproduces_the_shipped_entries_byte_for_byte(suite, data_root) -> None:
    # what `bench scenarios --regenerate --recording ...` prints comes from regenerate_suite
    lines: list[str] = []
    done = regenerate_suite(
        "crossings-v1", data_root, recordings=REGENERATED, progress=lines.append
    )
    regenerated = done.manifest
    assert regenerated["scenarios"], "the regenerated recordings must have scenarios"
    assert _entries(regenerated, REGENERATED) == _entries(suite.manifest, REGENERATED)
    assert (done.same, done.compared) == (True, "the shipped entries of 2 recording(s)")
    assert len(lines) == 3 and done.n_scenarios == len(regenerated["scenarios"])
    assert done.n_collisions == sum(
        int(s.collided_nolearn) for s in suite.scenarios if s.recording in REGENERATED
    )
    # one changed scenario is a difference, for the recordings' entries
    changed = copy.deepcopy(regenerated)
    changed["scenarios"][0]["max_frames"] += 1
    assert manifest_entries(changed, REGENERATED) != manifest_entries(suite.manifest, REGENERATED)
    assert manifest_entries(regenerated, REGENERATED) == manifest_entries(
        suite.manifest, REGENERATED
    )
    header = {k: v for k, v in regenerated.items() if k not in ("recordings", "scenarios")}
    shipped = {k: v for k, v in suite.manifest.items() if k not in ("recordings", "scenarios")}
    assert dump_manifest(header) == dump_manifest(shipped)


def test_geometry_of_an_ethucy_and_a_trajnet_recording_is_reproduced(suite, data_root) -> None:
    recs = ["ethucy:students001", "sdd:bookstore/video0:trajnet"]
    regenerated = generate_suite(CROSSINGS_V1, data_root, recordings=recs, nolearn=False)
    assert _entries(regenerated, recs, drop_nolearn=True) == _entries(
        suite.manifest, recs, drop_nolearn=True
    )


def _raw_pedestrians(sdd_dir: Path, scene: str, video: int) -> dict[int, np.ndarray]:
    """frame -> (n, 2) pedestrian positions in metres, read straight from the text file."""
    path = sdd_dir / "annotations" / scene / f"video{video}" / "annotations.txt"
    rows = np.loadtxt(path, dtype=str)
    scales = yaml.safe_load((sdd_dir / "estimated_scales.yaml").read_text())
    m_per_px = float(scales[scene][f"video{video}"]["scale"])
    keep = (rows[:, 9] == '"Pedestrian"') & (rows[:, 6] == "0")
    box = rows[keep][:, 1:5].astype(float)
    frame = rows[keep][:, 5].astype(int)
    centre = np.column_stack([box[:, 0] + box[:, 2], box[:, 1] + box[:, 3]]) * 0.5 * m_per_px
    return {f: centre[frame == f] for f in np.unique(frame)}


def test_scenario_runs_and_its_collisions_match_the_raw_annotations(suite, sdd_dir) -> None:
    sc = next(
        s for s in suite.scenarios if s.recording == "sdd:little/video0" and s.collided_nolearn
    )
    scene = load_scenario(sc, sdd_dir.parent)
    assert scene.start_frame == sc.start_frame and scene.meta["max_frames"] == sc.max_frames
    np.testing.assert_allclose(scene.start, sc.start_m)
    res = run_episode(
        scene,
        "constant_velocity",
        # the parameters the suite's record was made with (the edge rule pinned off)
        {**scene.meta["published_params"], **suite.manifest["nolearn"]["params"]},
        units="scene",
        learn=False,
        max_frames=sc.max_frames,
        record_animation=False,
    )
    assert res.metrics["n_collide"] == sc.nolearn["n_collide"] > 0
    assert res.metrics["frames"] <= sc.max_frames + 1
    # independently of the episode code: robot positions vs pedestrians from the text file
    peds = _raw_pedestrians(sdd_dir, "little", 0)
    si = res.config["params"]["si"]
    d_c = si["robot_radius"] + si["agent_radius"]
    traj = res.trajectory
    n = 0
    for f, x, y in zip(traj["frame"], traj["x"], traj["y"], strict=True):
        p = peds.get(int(f))
        if p is not None and p.size and np.min(np.hypot(p[:, 0] - x, p[:, 1] - y)) < d_c:
            n += 1
    assert n == res.metrics["n_collide"]


def test_cli_lists_a_split_and_refuses_unknown_suites(suite, capsys) -> None:
    assert main(["bench", "scenarios", "--suite", "crossings-v1", "--split", "test"]) == 0
    out = capsys.readouterr().out.splitlines()
    listed = [ln.split("\t")[0] for ln in out if ln and not ln.startswith(("#", "id\t"))]
    assert listed == [s.id for s in suite.scenarios_for("test")]
    n_col = sum(bool(s.collided_nolearn) for s in suite.scenarios_for("test"))
    assert f"# crossings-v1: {len(listed)} scenario(s), {n_col} with a nolearn collision" in out
    assert main(["bench", "scenarios", "--suite", "nope-v1"]) == 2
    assert "unknown suite" in capsys.readouterr().err


def test_cli_regenerates_one_recording(capsys, data_root) -> None:
    rc = main(
        [
            "bench",
            "scenarios",
            "--suite",
            "crossings-v1",
            "--regenerate",
            "--data-root",
            str(data_root),
            "--recording",
            "sdd:deathCircle/video2",
        ]
    )
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "byte-identical to the shipped entries of 1 recording(s)" in out


def test_shipped_scenarios_are_read_once_and_again_when_the_file_changes(
    suite, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    src = suites_module._manifest_dir() / "crossings-v1.json"
    (tmp_path / "crossings-v1.json").write_bytes(src.read_bytes())
    monkeypatch.setattr(suites_module, "_manifest_dir", lambda: tmp_path)
    monkeypatch.setattr(suites_module, "_SCENARIOS", {})
    first = suite.scenarios[0]
    a = shipped_scenario("crossings-v1", first.id)
    assert a == first
    assert shipped_scenario("crossings-v1", first.id) is a  # the same (frozen) instance
    manifest = json.loads((tmp_path / "crossings-v1.json").read_text())
    manifest["scenarios"][0]["max_frames"] += 1
    (tmp_path / "crossings-v1.json").write_text(dump_manifest(manifest))
    b = shipped_scenario("crossings-v1", first.id)
    assert b.max_frames == first.max_frames + 1  # the edited file was read again
    with pytest.raises(ValueError, match="has no scenario 'nope'"):
        shipped_scenario("crossings-v1", "nope")
    with pytest.raises(ValueError, match="unknown suite 'crossings-v9'"):
        shipped_scenario("crossings-v9", first.id)


# ------------------------------------------------------------------ crossings-v2
def test_v2_replays_biwi_eth_on_its_original_clock(data_root) -> None:
    """crossings-v2's biwi_eth scenarios read the recording at 0.667 s per row: walking
    speeds, where v1's 0.4 s gives 2.45 m/s."""
    from conformal_control.experiments.bench.generator import CROSSINGS_V2

    v1, v2 = load_suite("crossings-v1"), load_suite("crossings-v2")
    validate_manifest(v2.manifest)
    assert v2.manifest["version"] == 2 and "original clock" in v2.manifest["description"]
    assert "scene's default" in v2.manifest["nolearn"]["note"]
    eth1 = [s for s in v1.scenarios if "biwi_eth" in s.recording]
    eth2 = [s for s in v2.scenarios if "biwi_eth" in s.recording]
    assert {s.scene for s in eth1} == {"ethucy:biwi_eth"}
    assert {s.scene for s in eth2} == {"ethucy:biwi_eth:corrected"}
    # every other recording is the same in both suites
    others1 = [s for s in v1.scenarios if "biwi_eth" not in s.recording]
    others2 = [s for s in v2.scenarios if "biwi_eth" not in s.recording]
    strip = ("nolearn",)
    assert [{k: v for k, v in s.__dict__.items() if k not in strip} for s in others1] == [
        {k: v for k, v in s.__dict__.items() if k not in strip} for s in others2
    ]
    speeds = {}
    for sc in (eth1[0], eth2[0]):
        scene = load_scenario(sc, data_root)
        v = np.hypot(*np.diff(scene.positions, axis=0).T) * scene.fps
        speeds[sc.scene] = float(np.nanmedian(v))
    assert speeds["ethucy:biwi_eth"] > 2.0
    assert 1.0 < speeds["ethucy:biwi_eth:corrected"] < 1.7
    # the generator reproduces the corrected recording's scenarios
    rec = ["ethucy:biwi_eth:corrected"]
    regenerated = generate_suite(CROSSINGS_V2, data_root, recordings=rec, nolearn=False)
    assert _entries(regenerated, rec, drop_nolearn=True) == _entries(
        v2.manifest, rec, drop_nolearn=True
    )


def test_v2_nolearn_record_is_the_benchmark_nolearn(data_root) -> None:
    """v2 records the nolearn outcome with the scenes' defaults: bench run's nolearn, with
    the edge rule pinned off as the record is (issue 30)."""
    from conformal_control.experiments.bench.methods import expand_methods

    v2 = load_suite("crossings-v2")
    sc = next(s for s in v2.scenarios_for("test") if s.nolearn and s.nolearn["n_collide"] > 0)
    (m,) = expand_methods(["nolearn"])
    kw = m.run_kwargs()
    kw["params"] = {**kw.get("params", {}), **v2.manifest["nolearn"]["params"]}
    assert kw["params"]["edge"] == "paper"
    res = run_episode(
        load_scenario(sc, data_root), **kw, max_frames=sc.max_frames, record_animation=False
    )
    assert res.metrics["n_collide"] == sc.nolearn["n_collide"]
    assert round(res.metrics["d_min"], 3) == sc.nolearn["d_min"]


@pytest.mark.parametrize("name", ["crossings-v1", "crossings-v2"])
def test_the_docs_suite_tables_are_the_manifests(name) -> None:
    """The Benchmark page's count tables (scenarios, nolearn collisions and goals per source
    and split) are the manifests' (a stale table once said 29 / 85 for v1's 28 / 86)."""
    root = Path(__file__).resolve().parents[3]
    text = (root / "docs" / "benchmark.md").read_text()
    section = text.split(f"### `{name}`", 1)[1].split("\n### ", 1)[0]
    table = [
        [c.strip() for c in line.strip("|").split("|")]
        for line in section.splitlines()
        if line.startswith("| ") and line.split("|")[2].strip() in ("dev", "test")
    ]
    suite = load_suite(name)
    expect = []
    for src in ("sdd", "trajnet", "ethucy", "**all**"):
        for split in ("dev", "test"):
            scs = [
                s for s in suite.scenarios
                if s.split == split and (src == "**all**" or s.source == src)
            ]  # fmt: skip
            expect.append(
                [
                    src,
                    split,
                    str(len(scs)),
                    str(sum(bool(s.collided_nolearn) for s in scs)),
                    str(sum(bool(s.nolearn["goal_reached"]) for s in scs)),
                ]
            )
    assert [[r[0], r[1], r[3], r[4], r[5]] for r in table] == expect


def test_a_suite_without_a_generator_is_refused_before_any_work() -> None:
    with pytest.raises(ValueError, match="no generator for suite 'fcp-planar'"):
        regenerate_suite("fcp-planar")


def test_the_scenario_table_and_its_summary_per_split(suite) -> None:
    rows = suite.table("test")
    assert [r["id"] for r in rows] == [s.id for s in suite.scenarios_for("test")]
    first = suite.scenarios_for("test")[0]
    assert rows[0]["density"] == first.stats.get("corridor_density")
    assert rows[0]["nolearn_collide"] == first.nolearn["n_collide"]
    by_split = suite.summary("test")
    assert {r["split"] for r in by_split} == {"test"}
    assert sum(r["scenarios"] for r in by_split) == len(rows)
    assert sum(r["nolearn_collision"] for r in by_split) == sum(
        int(bool(s.collided_nolearn)) for s in suite.scenarios_for("test")
    )
    assert suite.summary() == suite.summary(None) and len(suite.summary()) > len(by_split)
