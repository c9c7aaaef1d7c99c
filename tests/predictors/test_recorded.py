"""The ``recorded`` predictor: CSV predictions replayed in closed loop, tested on the
Trajectron++ predictions of ``external/trajectron-ethucy`` (eth, hotel, zara1)."""

from __future__ import annotations

import gzip

import numpy as np
import pytest

from conformal_control.predictors import PredictionQuery
from conformal_control.predictors.recorded import RecordedPredictor, read_predictions

TRAJECTRON = "external/trajectron-ethucy"


def _raw(path):
    with gzip.open(path, "rt") as fh:
        return np.loadtxt(fh, delimiter=",", skiprows=1)


def _query(ids, current, *, frame, dt, horizon, scene="biwi_eth"):
    hist = np.full((len(ids), 3, 2), np.nan)
    hist[:, -1] = current
    return PredictionQuery(
        ids=np.asarray(ids), history=hist, dt=dt, horizon=horizon, frame=frame, scene=scene
    )


@pytest.mark.parametrize("name", ["eth", "hotel", "zara1"])
def test_returns_the_csv_values_exactly_at_sample_times(data_root, name):
    path = data_root / TRAJECTRON / f"{name}.csv.gz"
    raw = _raw(path)
    rec = read_predictions(path)
    assert rec.n_rows == raw.shape[0]
    pred = RecordedPredictor(str(path), step_s=0.4, frames_per_step=10)
    for k in (0, len(rec.frames) // 2, len(rec.frames) - 1):
        f = int(rec.frames[k])
        rows = raw[raw[:, 0] == f]
        ids = np.unique(rows[:, 1]).astype(int)
        # the ETH/UCY scenes' 30 fps clock: sample index f / 10 is frame 12 f / 10
        q = _query(ids, np.zeros((ids.size, 2)), frame=f * 12 // 10, dt=1 / 30, horizon=144)
        out = pred.predict(q).positions
        q25 = _query(ids, np.zeros((ids.size, 2)), frame=f // 10, dt=0.4, horizon=12)
        out25 = pred.predict(q25).positions
        for _, tid, step, x, y in rows:
            i = int(np.flatnonzero(ids == tid)[0])
            s = int(step)
            assert out[i, 12 * s - 1].tolist() == [x, y]  # bit for bit
            assert out25[i, s - 1].tolist() == [x, y]


def test_interpolates_between_the_current_position_and_the_forecast(data_root):
    path = data_root / TRAJECTRON / "eth.csv.gz"
    rec = read_predictions(path)
    f = int(rec.frames[3])
    ids = rec.ids[3][:2]
    pts = rec.points[3][:2]
    cur = pts[:, 0] - np.array([0.4, 0.0])  # anywhere: the anchor at the query's time
    # 4 frames (0.133 s) after the issue time: the forecast of that issue is used
    q = _query(ids, cur, frame=f * 12 // 10 + 4, dt=1 / 30, horizon=8)
    out = RecordedPredictor(str(path)).predict(q).positions
    t = np.arange(1, 9) / 30
    t_knots = np.array([0.0, 0.4 - 4 / 30, 0.8 - 4 / 30])
    for i in range(2):
        for ax in range(2):
            expect = np.interp(t, t_knots, [cur[i, ax], pts[i, 0, ax], pts[i, 1, ax]])
            np.testing.assert_allclose(out[i, :, ax], expect, atol=1e-12)


def test_missing_entries_fall_back_and_are_counted(data_root):
    path = data_root / TRAJECTRON / "eth.csv.gz"
    rec = read_predictions(path)
    f = int(rec.frames[10])
    known = rec.ids[10][:1]
    ids = np.array([known[0], 99999])
    hist = np.full((2, 6, 2), np.nan)
    hist[:, -3:] = np.array([[0.0, 0.0], [0.1, 0.0], [0.2, 0.0]])
    q = PredictionQuery(
        ids=ids, history=hist, dt=1 / 30, horizon=4, frame=f * 12 // 10, scene="biwi_eth"
    )
    fc = RecordedPredictor(str(path)).predict(q)
    assert fc.info["n_missing"] == 1
    # the unknown agent is predicted by constant velocity (3 m/s along x)
    np.testing.assert_allclose(fc.positions[1, :, 0], 0.2 + 0.1 * np.arange(1, 5))
    # before the first forecast was issued: everyone falls back
    early = PredictionQuery(ids=ids, history=hist, dt=1 / 30, horizon=4, frame=0, scene="biwi_eth")
    assert RecordedPredictor(str(path)).predict(early).info["n_missing"] == 2


def test_ids_and_positions_match_the_recording(data_root):
    """The forecasts' agents are the recording's pedestrians present at the issue frame."""
    path = data_root / TRAJECTRON / "eth.csv.gz"
    rec = read_predictions(path)
    table = np.loadtxt(data_root / "ethucy/eth/test/biwi_eth.txt")
    for k in (5, 50, 200):
        f = rec.frames[k]
        present = set(table[table[:, 0] == f, 1].astype(int).tolist())
        assert set(rec.ids[k].tolist()) <= present


def test_scene_mapping_and_data_root(data_root):
    files = {"biwi_eth": f"{TRAJECTRON}/eth.csv.gz"}
    p = RecordedPredictor(files, data_root=str(data_root))
    p.reset()
    assert p.predictions("biwi_eth").n_rows > 60_000
    with pytest.raises(ValueError, match="no recorded predictions for scene 'biwi_hotel'"):
        p.predictions("biwi_hotel")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("frame,track_id,x,y\n1,2,3.0,4.0\n", "missing column.*step"),
        ("frame,track_id,step,x,y\n1,2,1,nan,4.0\n", r":2: non-finite value"),
        ("frame,track_id,step,x,y\n1,2,1,3.0\n", r":2: expected numbers"),
        ("frame,track_id,step,x,y\n1,2,0,3.0,4.0\n", "step an integer >= 1"),
        ("frame,track_id,step,x,y\n1,2,1,3.0,4.0\n1,2,1,3.5,4.0\n", "duplicated prediction"),
        ("frame,track_id,step,x,y\n", "no prediction rows"),
    ],
)
def test_malformed_files_are_one_line_errors(tmp_path, text, message):
    path = tmp_path / "p.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as exc:
        read_predictions(path)
    assert "\n" not in str(exc.value)


def test_gzip_and_plain_files_read_the_same(tmp_path):
    text = "track_id,frame,step,x,y,extra\n2,10,1,1.5,2.5,z\n2,10,2,2.0,3.0,z\n"
    plain = tmp_path / "p.csv"
    plain.write_text(text)
    packed = tmp_path / "p.csv.gz"
    with gzip.open(packed, "wt") as fh:
        fh.write(text)
    a, b = read_predictions(plain), read_predictions(packed)
    assert a.frames.tolist() == b.frames.tolist() == [10]
    assert np.array_equal(a.points[0], b.points[0])
    assert a.points[0][0].tolist() == [[1.5, 2.5], [2.0, 3.0]]


def test_bad_parameters(tmp_path):
    with pytest.raises(ValueError, match="step_s must be a finite number > 0"):
        RecordedPredictor("x.csv", step_s=0).reset()
    with pytest.raises(FileNotFoundError, match="predictions file not found"):
        RecordedPredictor(str(tmp_path / "none.csv")).predictions("s")


def test_closed_loop_on_a_biwi_hotel_scenario(data_root):
    """A dev scenario of biwi_hotel (Trajectron++'s hotel predictions) runs on the batch
    engine as on the loop, and its forecasts come from the file."""
    from conformal_control.experiments.bench import load_scenario, load_suite
    from conformal_control.runs.engines.batch import run_batch
    from conformal_control.runs.episode import run_episode

    suite = load_suite("crossings-v1")
    sc = next(s for s in suite.scenarios if s.recording == "ethucy:biwi_hotel")
    scene = load_scenario(sc, data_root)
    params = {"path": str(data_root / TRAJECTRON / "hotel.csv.gz")}
    (batched,) = run_batch([scene], "recorded", predictor_params=params, max_frames=sc.max_frames)
    loop = run_episode(
        scene,
        "recorded",
        predictor_params=params,
        max_frames=sc.max_frames,
        engine="loop",
        record_animation=False,
    ).metrics
    da = {k: v for k, v in batched.as_dict().items() if k != "wall_s"}
    db = {k: v for k, v in loop.as_dict().items() if k != "wall_s"}
    assert da == db
    assert {"n_missing", "n_missing_steps", "n_extrapolated"} <= set(loop["predictor_info"])
    # the forecasts are the file's: the run is not the constant-velocity one
    cv = run_episode(
        scene, "constant_velocity", max_frames=sc.max_frames, record_animation=False
    ).metrics
    assert (loop["l_mean"], loop["d_min"]) != (cv["l_mean"], cv["d_min"])
