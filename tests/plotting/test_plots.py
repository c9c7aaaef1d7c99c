"""Figures: content of the run, distance and sweep plots (lines, markers, labels, thresholds)."""

from __future__ import annotations

import csv

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pytest

from conformal_control.plotting import (
    plot_distance,
    plot_lambda_loss,
    plot_run,
    plot_scene,
    plot_sweep,
)


@pytest.fixture(scope="module")
def crossing_run(crossing):
    from conformal_control.sim.episode import run_episode

    return run_episode(crossing, "constant_velocity", max_frames=60)


def _hlines(ax):
    """y values of horizontal lines (axhline) on the axes."""
    out = []
    for line in ax.get_lines():
        y = np.asarray(line.get_ydata(), dtype=float)
        if y.size == 2 and y[0] == y[1] and list(line.get_xdata()) == [0, 1]:
            out.append(float(y[0]))
    return out


def test_distance_plot_has_threshold_and_collisions():
    fig, ax = plt.subplots()
    traj = {"t": np.arange(5) * 0.1, "d_min": np.array([2.0, 1.0, 0.5, 0.8, 3.0])}
    plot_distance(ax, traj, 1.0, t_goal=0.4)
    assert _hlines(ax) == [1.0]
    crosses = [ln for ln in ax.get_lines() if ln.get_marker() == "x"]
    assert len(crosses) == 1 and len(crosses[0].get_xdata()) == 2  # frames with d < d_c
    assert ax.get_xlabel() == "t (s)" and ax.get_ylabel() == "distance (m)"
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "collision (2 frames)" in labels and "goal reached" in labels
    plt.close(fig)


def test_lambda_loss_plot_has_epsilon(crossing_run):
    fig, (a, b) = plt.subplots(2)
    plot_lambda_loss(a, b, crossing_run.intervals, -0.1, "1/s")
    assert _hlines(b) == [-0.1]
    n_scored = sum(iv["loss"] is not None for iv in crossing_run.intervals)
    assert len(a.get_lines()[0].get_xdata()) == n_scored
    assert a.get_ylabel() == "lambda (1/s)"
    plt.close(fig)


def test_scene_plot_marks_start_goal_path_and_collisions(crossing_run):
    fig, ax = plt.subplots()
    traj = dict(crossing_run.trajectory)
    traj["d_min"] = traj["d_min"].copy()
    traj["d_min"][:3] = 0.0  # pretend three collision frames
    plot_scene(ax, crossing_run.scene, traj)
    markers = {ln.get_label(): ln for ln in ax.get_lines()}
    assert markers["start"].get_marker() == "s" and markers["goal"].get_marker() == "*"
    assert len(markers["robot"].get_xdata()) == len(traj["x"])
    assert "collision (3 frames)" in markers
    plt.close(fig)


def test_run_figure_has_four_panels(crossing_run, tmp_path):
    fig = plot_run(crossing_run)
    assert len(fig.axes) == 4
    assert fig.axes[3].get_ylabel() == "distance (m)"
    assert _hlines(fig.axes[3]) == [crossing_run.scene.collision_distance]
    plt.close(fig)
    plot_run(crossing_run, tmp_path / "p.png")
    assert (tmp_path / "p.png").stat().st_size > 10_000


def test_sweep_plot_from_dicts_and_csv(tmp_path):
    rows = [
        {"epsilon": e, "seed": s, "t_goal": 10 + e + s, "n_collide": 0, "d_min": 1.0, "l_avg": e}
        for e in (-0.2, 0.0, 0.2)
        for s in (0, 1)
    ]
    fig = plot_sweep(rows, "epsilon", ("t_goal", "l_avg"))
    ax_t, ax_l = fig.axes
    line = ax_t.get_lines()[0]
    np.testing.assert_allclose(line.get_xdata(), [-0.2, 0.0, 0.2])
    np.testing.assert_allclose(line.get_ydata(), [10.3, 10.5, 10.7])  # mean over seeds
    assert ax_t.get_xlabel() == "epsilon" and ax_t.get_ylabel() == "t_goal (s)"
    assert "l_avg = epsilon" in [t.get_text() for t in ax_l.get_legend().get_texts()]
    plt.close(fig)
    path = tmp_path / "sweep.csv"
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    fig = plot_sweep(path, "epsilon", ("t_goal",), group="seed")
    assert len(fig.axes[0].get_lines()) == 2  # one line per seed
    plt.close(fig)


def test_sweep_plot_bad_input():
    with pytest.raises(ValueError, match="at least one"):
        plot_sweep([], "epsilon")
    with pytest.raises(ValueError, match="no result has the key 'eta'"):
        plot_sweep([{"epsilon": 0.0, "t_goal": 1.0}], "eta", ("t_goal",))


def test_plot_sweep_command(tmp_path, capsys):
    from conformal_control.cli import main

    path = tmp_path / "r.csv"
    path.write_text("eta,seed,d_min,l_avg\n0.1,0,1.0,-0.2\n0.1,1,1.2,-0.22\n1.0,0,0.9,-0.25\n")
    out = tmp_path / "s.png"
    argv = ["plot-sweep", str(path), "--x", "eta", "--metric", "d_min", "--out", str(out)]
    assert main(argv) == 0
    assert out.stat().st_size > 5_000
    assert "3 results plotted" in capsys.readouterr().out
    assert main(["plot-sweep", str(path), "--x", "tau", "--out", str(out)]) == 2
    assert "no result has the key 'tau'" in capsys.readouterr().err
