"""Collision accounting: constructed cases with known answers, the grid's proofs, and a
recomputation from the raw SDD annotations."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conformal_control.runs.results.collisions import (
    CLOSING_TOL,
    account_collisions,
    avoidable,
)

FPS = 10.0


def _account(robot_xy, robot_v, peds, *, v_max=1.0, sensing=10.0, every=4):
    """Accounting of a constructed episode: robot (F, 2) positions and (F, 2) velocities,
    pedestrians a list of (F, 2) tracks (NaN where absent)."""
    robot = np.column_stack([robot_xy, robot_v])
    pos = np.stack(peds, axis=1)
    return account_collisions(
        robot,
        np.arange(robot.shape[0]),
        pos,
        np.arange(len(peds)) + 1,
        fps=FPS,
        collision_distance=1.0,
        sensing_radius=sensing,
        v_max=v_max,
        sample_every=every,
    )


def _line(p0, v, n):
    t = np.arange(n)[:, None] / FPS
    return np.asarray(p0, float) + t * np.asarray(v, float)


def test_head_on():
    n = 60
    acc = _account(
        _line((0, 0), (1, 0), n), np.tile([1.0, 0.0], (n, 1)), [_line((6, 0), (-1, 0), n)]
    )
    (e,) = acc.events
    # distance 6 - 2t < 1 from t > 2.5 s to t < 3.5 s (they pass through each other)
    assert (e.t_start, e.frames) == (2.6, 9)
    assert acc.n_collide == 9 and acc.n_collision_events == 1
    assert e.closing == "both"
    assert (e.robot_closing, e.pedestrian_closing) == pytest.approx((1.0, 1.0))
    assert e.popin is False and e.avoidable is True and e.decided_by == "straight"
    assert e.penetration == pytest.approx(1.0)  # they meet at the centre (t = 3 s)
    # the robot closes until they meet, then moves away: 4 of the 9 frames are its fault
    assert acc.n_collide_at_fault == 4
    assert acc.n_collide_avoidable == 9 and acc.n_collide_popin == 0


def test_from_behind_into_a_moving_robot():
    n = 60
    acc = _account(
        _line((0, 0), (0.5, 0), n), np.tile([0.5, 0.0], (n, 1)), [_line((-4, 0), (2.0, 0), n)]
    )
    (e,) = acc.events
    assert e.closing == "pedestrian"  # the robot moves away from it
    assert (e.robot_closing, e.pedestrian_closing) == pytest.approx((-0.5, 2.0))
    # it overtakes the robot at t = 8/3 s; from then on the robot drives into its back
    assert acc.n_collide_at_fault == 7 and e.frames == 13
    assert e.avoidable is True  # stepping aside would have done
    assert acc.n_collide_avoidable == acc.n_collide > 0


def test_pop_in():
    n = 40
    ped = np.full((n, 2), np.nan)
    ped[21:] = _line((1.5, 0), (-0.5, 0), n)[: n - 21]  # a track starting 1.5 m away (2.1 s)
    far = _line((-9, 9), (0, 0), n)  # someone else, never close
    acc = _account(np.zeros((n, 2)), np.zeros((n, 2)), [ped, far])
    (e,) = acc.events
    assert e.popin is True and e.t_visible == 2.1
    assert e.closing == "pedestrian"
    # it walks in at 0.5 m/s: inside d_c from 3.2 s; sensed at the sampling time 2.4 s
    assert e.t_start == pytest.approx(3.2) and e.t_sensed == pytest.approx(2.4)
    assert e.avoidable is True  # stepping back in 0.8 s would have done
    # the rule: a pop-in's frames are counted apart and never as avoidable
    assert acc.n_collide_popin == acc.n_collide > 0 and acc.n_collide_avoidable == 0
    assert acc.n_collide_unavoidable == 0


def test_pop_in_inside_the_collision_distance_is_unsensed():
    n = 30
    ped = np.full((n, 2), np.nan)
    ped[21:] = [0.5, 0.0]  # appears 0.5 m away between two sampling times
    acc = _account(np.zeros((n, 2)), np.zeros((n, 2)), [ped])
    (e,) = acc.events
    assert e.popin and e.t_start == pytest.approx(2.1) and e.t_sensed == pytest.approx(2.4)
    assert (e.avoidable, e.decided_by) == (False, "unsensed")
    assert e.closing == "neither"


def test_provably_unavoidable():
    """A pedestrian running at 6 m/s at a robot limited to 0.5 m/s, visible 4.8 m away."""
    n = 20
    acc = _account(
        np.zeros((n, 2)), np.zeros((n, 2)), [_line((5.4, 0), (-6, 0), n)], v_max=0.5, sensing=5.0
    )
    (e,) = acc.events
    assert e.t_visible == pytest.approx(0.1) and e.t_sensed == pytest.approx(0.4)
    assert e.popin is False  # visible 4.8 m away, 0.7 s before
    assert e.avoidable is False and e.decided_by == "covered"
    assert acc.n_collide_unavoidable == acc.n_collide > 0
    assert acc.n_collide_avoidable == 0


def test_no_collision_no_event():
    n = 30
    acc = _account(np.zeros((n, 2)), np.zeros((n, 2)), [_line((3, 3), (0, 0), n)])
    assert acc.events == [] and acc.n_collide == 0 and acc.penetration_max is None


def test_frames_are_attributed_to_the_nearest_pedestrian():
    n = 30
    a = _line((0.5, 0), (0, 0), n)  # always inside
    b = np.full((n, 2), np.nan)
    b[10:20] = [0.2, 0.0]  # closer for 10 frames
    acc = _account(np.zeros((n, 2)), np.zeros((n, 2)), [a, b])
    by_agent = {e.agent: e for e in acc.events}
    assert by_agent[1].frames == 30 and by_agent[1].frames_attributed == 20
    assert by_agent[2].frames == 10 and by_agent[2].frames_attributed == 10
    assert acc.n_collide == 30  # frames, not pairs
    assert acc.penetration_max == pytest.approx(0.8)


# ------------------------------------------------------------------ the avoidability test
def _ring() -> np.ndarray:
    """A pedestrian circling the robot's start at 1.2 m, two turns per second (at 10 fps
    it visits five places, one frame in five each): the robot stays within about 0.3 m of
    its start for the 10 frames."""
    th = 4 * np.pi / 10 * np.arange(1, 11)
    return 1.2 * np.column_stack([np.cos(th), np.sin(th)])


def _axis(a: float, b: float, n: int) -> np.ndarray:
    return np.column_stack([np.linspace(a, b, n), np.zeros(n)])


def test_a_turn_that_only_the_grid_finds():
    """Wait inside the ring, then leave sideways before it comes back along the x axis:
    every straight path is too slow to survive the ring and too slow to leave in time."""
    q = np.vstack([_ring(), _axis(1.56, 3.0, 5), _axis(2.8, 0.0, 15), _axis(-0.2, -2.0, 10)])
    k = np.arange(1, len(q) + 1)
    verdict, how = avoidable(np.zeros(2), q, k, v_max=1.0, dt=1 / FPS, d_c=1.0)
    assert (verdict, how) == (True, "grid")


def test_a_trap_that_only_the_grid_proves():
    """The same ring, then it crosses the start 0.2 s later: no path, although the
    reachable disk is never covered at once."""
    q = np.vstack([_ring(), [[0.6, 0.0], [0.0, 0.0]], _axis(-0.6, -5.0, 8)])
    k = np.arange(1, len(q) + 1)
    assert not (np.hypot(*q.T) + 0.1 * k < 1.0).any()
    verdict, how = avoidable(np.zeros(2), q, k, v_max=1.0, dt=1 / FPS, d_c=1.0)
    assert (verdict, how) == (False, "grid")


@settings(max_examples=40, deadline=None)
@given(
    st.floats(-3, 3),
    st.floats(-3, 3),
    st.floats(-4, 4),
    st.floats(-4, 4),
    st.floats(0.3, 2.0),
    st.integers(5, 30),
)
def test_the_grid_never_contradicts_the_closed_form_tests(x, y, vx, vy, v_max, n):
    """Straight-line pedestrians: when the covering test proves a collision, the grid finds
    no path; when a straight escape exists, the grid does not prove there is none."""
    from conformal_control.runs.results.collisions import _grid, _straight

    k = np.arange(1, n + 1)
    q = np.array([x, y]) + np.outer(k / FPS, [vx, vy])
    r = v_max / FPS
    covered = bool((np.hypot(*q.T) + r * k < 1.0).any())
    grid = _grid(np.zeros(2), q, k, r, 1.0, r / 4)
    if covered:
        assert grid is not True
    if _straight(np.zeros(2), q, k, r, 1.0):
        assert grid is not False


# ------------------------------------------------------------------ recomputation
def test_recomputed_from_the_raw_sdd_annotations(data_root):
    """An SDD test scenario's collision frames and events, recomputed from the raw
    annotations file (its own parser, not the loader) and the robot's logged path."""
    from conformal_control.data.sdd import sdd_video
    from conformal_control.experiments.bench import load_scenario, load_suite
    from conformal_control.runs.episode import run_episode

    sc = load_suite("crossings-v1").scenario("sdd-hyang-13-w017")
    scene = load_scenario(sc, data_root)
    res = run_episode(
        scene, "constant_velocity", learn=False, max_frames=sc.max_frames, record_animation=False
    )
    m, traj = res.metrics, res.trajectory
    assert m["n_collide"] > 0
    vid = sdd_video("hyang", 13, data_root)
    tracks: dict[int, dict[int, tuple[float, float]]] = {}
    with open(vid.annotations) as fh:
        for line in fh:
            p = line.split()
            if p[9] != '"Pedestrian"' or p[6] != "0":
                continue
            x = (float(p[1]) + float(p[3])) / 2 * vid.m_per_px
            y = (float(p[2]) + float(p[4])) / 2 * vid.m_per_px
            tracks.setdefault(int(p[0]), {})[int(p[5])] = (x, y)
    d_c = res.scene.collision_distance
    runs: dict[int, list[int]] = {}
    n_collide = 0
    for i, (f, rx, ry) in enumerate(zip(traj["frame"], traj["x"], traj["y"], strict=True)):
        dist = {
            tid: float(np.hypot(t[f][0] - rx, t[f][1] - ry)) for tid, t in tracks.items() if f in t
        }
        close = [tid for tid, d in dist.items() if d < d_c]
        n_collide += bool(close)
        for tid in close:
            runs.setdefault(tid, []).append(i)
    events = []
    for tid, idx in runs.items():
        start = idx[0]
        for a, b in zip(idx, [*idx[1:], None], strict=True):
            if b != a + 1:
                events.append((tid, start, a - start + 1))
                start = b
    got = sorted(
        (e["agent"], round(e["t_start"] * scene.fps), e["frames"]) for e in m["collision_events"]
    )
    assert n_collide == m["n_collide"]
    assert got == sorted(events)
    assert m["n_collision_events"] == len(events)
    parts = (
        "n_collide_avoidable",
        "n_collide_unavoidable",
        "n_collide_undecided",
        "n_collide_popin",
    )
    assert sum(m[k] for k in parts) == m["n_collide"]
    assert all(e["avoidable"] is not None for e in m["collision_events"])
    assert 0 <= m["n_collide_at_fault"] <= m["n_collide"]
    assert CLOSING_TOL > 0
