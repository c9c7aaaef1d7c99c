"""The Rerun export read back: entities, counts, times and values equal the run's files."""

from __future__ import annotations

import numpy as np
from rerun.chunk import RrdReader

from conformal_control.io.export import export_run


def _columns(path):
    """entity path -> {column name: list of values} over every chunk, in time order."""
    out: dict[str, dict[str, list]] = {}
    for chunk in RrdReader(path).stream():
        cols = chunk.to_record_batch().to_pydict()
        dst = out.setdefault(chunk.entity_path, {})
        for name, values in cols.items():
            dst.setdefault(name, []).extend(values)
    for cols in out.values():
        if "time" in cols:
            order = np.argsort([t.value for t in cols["time"]], kind="stable")
            for name in cols:
                cols[name] = [cols[name][i] for i in order]
    return out


def _ns(t: float) -> int:
    return round(t * 1e9)


def test_single_run_entities_counts_and_values(single_run, read_csv):
    path = export_run(single_run, format="rerun")
    assert path == single_run / "run.rrd"
    ent = _columns(path)
    traj = read_csv(single_run / "trajectory.csv")
    intervals = read_csv(single_run / "intervals.csv")
    trace = read_csv(single_run / "trace.csv")
    anim = np.load(single_run / "animation.npz")
    lam = ent["/plots/robot/lambda"]
    assert [t.value for t in lam["time"]] == [_ns(r["t"]) for r in intervals]
    assert [v[0] for v in lam["Scalars:scalars"]] == [r["lambda"] for r in intervals]
    loss = ent["/plots/robot/loss"]
    assert [t.value for t in loss["time"]] == [_ns(r["t"]) for r in trace]
    assert [v[0] for v in loss["Scalars:scalars"]] == [r["loss"] for r in trace]
    d = ent["/plots/robot/d_min"]
    assert [v[0] for v in d["Scalars:scalars"]] == [r["d_min"] for r in traj]
    assert [t.value for t in d["time"]] == [_ns(r["t"]) for r in traj]
    robot = ent["/world/robot"]
    assert len(robot["time"]) == len(traj)
    np.testing.assert_array_equal(
        np.array([p[0] for p in robot["Points2D:positions"]]), anim["robot"]
    )
    peds = ent["/world/pedestrians"]
    counts = np.isfinite(anim["peds"][..., 0]).sum(axis=1)
    assert [len(p) for p in peds["Points2D:positions"]] == counts.tolist()
    np.testing.assert_array_equal(
        np.concatenate([np.array(p).reshape(-1, 2) for p in peds["Points2D:positions"]]),
        anim["peds"][np.isfinite(anim["peds"][..., 0])],
    )
    with_preds = int((anim["pred_cols"] >= 0).any(axis=1).sum())
    assert len(ent["/world/predictions"]["time"]) == with_preds > 0


def test_multi_robot_run(multi_run, read_csv):
    ent = _columns(export_run(multi_run, format="rerun"))
    for i in range(3):
        intervals = read_csv(multi_run / "robots" / f"robot_{i:02d}" / "intervals.csv")
        lam = ent[f"/plots/robot_{i}/lambda"]["Scalars:scalars"]
        assert [v[0] for v in lam] == [r["lambda"] for r in intervals]
        assert f"/world/robot_{i}" in ent
    frames = np.load(multi_run / "animation.npz")["t"].size
    assert len(ent["/world/pedestrians"]["time"]) == frames


def test_start_time_makes_the_timeline_a_date(single_run, tmp_path):
    plain = _columns(export_run(single_run, tmp_path / "plain.rrd", format="rerun"))
    dated = _columns(
        export_run(
            single_run, tmp_path / "dated.rrd", format="rerun", start_time="2026-05-04T09:30:00"
        )
    )
    offset = 1_777_887_000 * 10**9
    lam, lam_dated = plain["/plots/robot/lambda"], dated["/plots/robot/lambda"]
    assert [t.value + offset for t in lam["time"]] == [
        np.datetime64(t, "ns").astype(np.int64) for t in lam_dated["time"]
    ]
