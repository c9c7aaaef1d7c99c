"""Figures: content of the run, distance and sweep plots (lines, markers, labels, thresholds)."""

from __future__ import annotations

import csv

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pytest

from conformal_control.io.plotting import (
    plot_distance,
    plot_lambda_loss,
    plot_run,
    plot_scene,
    plot_sweep,
)


@pytest.fixture(scope="module")
def crossing_run(crossing):
    from conformal_control.runs.episode import run_episode

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


def test_distance_axis_clips_a_spike_and_says_so():
    fig, ax = plt.subplots()
    d = np.full(100, 2.0)
    d[40] = 0.8  # a near miss
    d[70] = 53.0  # nobody near: the nearest pedestrian is far away
    plot_distance(ax, {"t": np.arange(100) * 0.1, "d_min": d}, 1.0)
    lo, hi = ax.get_ylim()
    assert lo == 0 and 1.0 < hi < 10  # d_c stays readable
    assert "clipped" in ax.get_ylabel() and ax.get_ylabel().startswith("distance (m)")
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any("1 frames above" in t and "max 53" in t for t in labels)
    plt.close(fig)
    fig, ax = plt.subplots()  # no spike: the data, not clipped
    plot_distance(ax, {"t": np.arange(100) * 0.1, "d_min": np.linspace(0.5, 3, 100)}, 1.0)
    assert ax.get_ylabel() == "distance (m)"
    np.testing.assert_allclose(ax.get_ylim(), (0, 3.15))
    plt.close(fig)


def _monitor(rule, losses, **kw):
    from conformal_control.core.monitor import GuaranteeMonitor

    m = GuaranteeMonitor.for_rule(rule, **kw)
    for x in losses:
        m.update(float(x))
    return m


def test_guarantee_plot_keeps_bounds_in_the_loss_range():
    from conformal_control.core.update_rules import FixedEtaRule, PIDRule
    from conformal_control.io.plotting import plot_guarantee

    losses = np.random.default_rng(0).uniform(-0.1, 0.1, 60)
    # fixed step with lambda_safe: the Theorem-2 bound ends inside the axes
    m = _monitor(FixedEtaRule(epsilon=0.0, eta=1.0), losses, lambda_safe=-0.5)
    fig = plot_guarantee(m)
    ax = fig.axes[0]
    lo, hi = ax.get_ylim()
    bound = next(ln for ln in ax.get_lines() if ln.get_label().startswith("Theorem-2 bound"))
    assert lo < m.bound_trace()[-1] < hi and -0.5 <= lo and hi <= 0.5
    assert np.nanmax(bound.get_ydata()) <= 0.5  # the part above the loss range is not drawn
    assert "verdict: " in bound.get_label()
    assert ax.get_ylabel() == "loss (dimensionless)" and fig.axes[1].get_xlabel() == "update k"
    plt.close(fig)
    # PID with a wide saturation: its long-run bound covers (-1/2, 1/2): annotated, not drawn
    m = _monitor(PIDRule(epsilon=0.0, eta=0.1, K_I=0.5, C_sat=5.0), losses)
    assert m.long_run_trace()[-1] > 1.0
    fig = plot_guarantee(m)
    ax = fig.axes[0]
    assert not ax.collections  # no band
    lo, hi = ax.get_ylim()
    assert hi - lo < 0.5  # zoomed on the losses, not stretched to the band
    notes = [t.get_text() for t in ax.texts]
    assert any("long-run bound" in t and "vacuous" in t for t in notes)
    plt.close(fig)
    # a narrower band is drawn, clipped to the loss range
    m = _monitor(PIDRule(epsilon=0.0, eta=0.1, K_I=0.5, C_sat=1.0), losses)
    fig = plot_guarantee(m)
    (band,) = fig.axes[0].collections
    ys = np.concatenate([p.vertices[:, 1] for p in band.get_paths()])
    assert ys.min() >= -0.5 and ys.max() <= 0.5
    plt.close(fig)


def test_guarantee_plot_per_agent():
    """lambda per agent: one point per agent (hollow under 10 losses), each agent's bound,
    the clipped agents ringed, one lambda line per agent and the floor."""
    from conformal_control.core.monitor import AgentMonitor
    from conformal_control.core.update_rules import FixedEtaRule
    from conformal_control.io.plotting import plot_guarantee

    rule = FixedEtaRule(epsilon=0.0, eta=1.0, lambda_min=-0.3)
    m = AgentMonitor.for_rule(rule, lambda_safe=-0.2)
    rng = np.random.default_rng(0)
    for k in range(30):
        keys = [1, 2] if k < 25 else [1, 2, 3]
        m.values(keys)  # agent 3 gets an entry (at the prior) when it first appears
        losses = np.where(np.array(keys) == 2, 0.45, rng.uniform(-0.01, 0.01, len(keys)))
        m.update(keys, losses)
    fig = plot_guarantee(m)
    ax, ax_l = fig.axes[:2]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "agent, >= 10 losses (2)" in labels and "agent, fewer losses (1)" in labels
    assert any(x.startswith("each agent's bound") for x in labels)
    assert "lambda clipped at some update (1)" in labels  # agent 2, pushed to the floor
    assert len(ax_l.get_lines()) == 4  # three agents and the floor
    assert ax_l.get_lines()[-1].get_ydata()[0] == -0.3
    plt.close(fig)


def _sweep_rows():
    return [
        {
            "epsilon": e,
            "eta": eta,
            "seed": s,
            "t_goal": 10 + e + s + eta,
            "n_collide": 0,
            "d_min": 1.0,
            "l_avg": e,
            "fallback_share": 0.1 * s,  # a metric that varies: not a parameter
        }
        for e in (-0.2, 0.0, 0.2)
        for eta in (0.1, 1.0)
        for s in (0, 1)
    ]


def test_sweep_plot_one_line_per_varying_parameter(tmp_path):
    rows = _sweep_rows()
    fig = plot_sweep(rows, "epsilon", ("t_goal", "n_collide", "l_avg"))
    ax_t, ax_c, ax_l = fig.axes
    lines = {ln.get_label(): ln for ln in ax_t.get_lines()}
    assert set(lines) == {"eta = 0.1", "eta = 1"}  # eta is not averaged away
    np.testing.assert_allclose(lines["eta = 0.1"].get_xdata(), [-0.2, 0.0, 0.2])
    np.testing.assert_allclose(lines["eta = 0.1"].get_ydata(), [10.4, 10.6, 10.8])  # seeds
    # one x label for the panels (none overlaps), the y label of each metric
    assert fig.get_supxlabel().startswith("epsilon") and ax_t.get_xlabel() == ""
    assert ax_t.get_ylabel() == "t_goal (s)"
    legend = ax_l.get_legend()
    assert "l_avg = epsilon" in [t.get_text() for t in legend.get_texts()]
    # what each point averages, under the title
    assert fig.get_suptitle().endswith("\neach point: mean over 2 seeds (min-max shaded)")
    # lines that coincide stay visible: every line has its own style and marker
    styles = {(ln.get_linestyle(), ln.get_marker()) for ln in ax_t.get_lines()}
    assert len(styles) == len(ax_t.get_lines())
    # collision frames: an integer axis from 0
    assert ax_c.get_ylim()[0] == 0 and ax_c.get_ylim()[1] >= 1
    assert all(float(t).is_integer() for t in ax_c.get_yticks())
    assert "t_goal, n_collide, l_avg against epsilon (12 runs)" in fig.get_suptitle()
    plt.close(fig)
    # lines only per seed: eta is averaged, and the figure says so
    fig = plot_sweep(rows, "epsilon", ("t_goal",), group="seed")
    ax = fig.axes[0]
    assert [ln.get_label() for ln in ax.get_lines()] == ["seed = 0", "seed = 1"]
    assert fig.get_suptitle().endswith("\neach point: averaged over eta in {0.1, 1}")
    plt.close(fig)


def test_sweep_plot_reads_the_runner_csv(tmp_path):
    """results.csv has param.* columns; --x epsilon finds param.epsilon."""
    rows = [
        {
            "key": f"k{i}",
            "status": "ok",
            "scene": "crossing",
            "predictor": "constant_velocity",
            "seed": 0,
            "param.epsilon": e,
            "param.tau": tau,
            "t_goal": 9 + e,
            "l_avg": e,
            "run_dir": f"runs/{i}",
        }
        for i, (e, tau) in enumerate([(-0.1, 4), (0.1, 4), (-0.1, 8), (0.1, 8)])
    ]
    path = tmp_path / "results.csv"
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    fig = plot_sweep(path, "epsilon", ("t_goal",))
    ax = fig.axes[0]
    assert [ln.get_label() for ln in ax.get_lines()] == ["tau = 4", "tau = 8"]
    assert fig.get_suptitle() == "crossing: t_goal against epsilon (4 runs)\neach point: one run"
    plt.close(fig)


def test_sweep_plot_bad_input():
    with pytest.raises(ValueError, match="at least one"):
        plot_sweep([], "epsilon")
    with pytest.raises(ValueError, match="no result has the key 'eta'"):
        plot_sweep([{"epsilon": 0.0, "t_goal": 1.0}], "eta", ("t_goal",))


def test_plot_sweep_command_writes_beside_the_results(tmp_path, capsys, monkeypatch):
    from conformal_control.cli import main

    monkeypatch.chdir(tmp_path)
    sweep = tmp_path / "sweep1"
    sweep.mkdir()
    path = sweep / "r.csv"
    path.write_text("eta,seed,d_min,l_avg\n0.1,0,1.0,-0.2\n0.1,1,1.2,-0.22\n1.0,0,0.9,-0.25\n")
    assert main(["plot-sweep", str(path), "--x", "eta", "--metric", "d_min"]) == 0
    out = sweep / "sweep-eta.png"
    assert out.stat().st_size > 5_000 and not (tmp_path / "sweep.png").exists()
    assert f"3 results plotted to {out}" in capsys.readouterr().out
    other = tmp_path / "s.png"
    argv = ["plot-sweep", str(path), "--x", "eta", "--metric", "l_avg", "--out", str(other)]
    assert main(argv) == 0
    assert other.stat().st_size > 5_000
    assert main(["plot-sweep", str(path), "--x", "tau", "--out", str(other)]) == 2
    assert "no result has the key 'tau'" in capsys.readouterr().err


def _paths_runs(scene, n):
    from conformal_control.runs.episode import run_episode

    res = run_episode(scene, "constant_velocity", max_frames=30)
    runs = []
    for i in range(n):
        runs.append(
            {
                "label": f"row {i}",
                "trajectory": res.trajectory,
                "metrics": res.metrics,
                "learn": True,
                "epsilon": -0.1,
                "intervals": {
                    "t": np.array([iv["t"] for iv in res.intervals], dtype=float),
                    "lambda": np.array([iv["lambda"] for iv in res.intervals], dtype=float),
                    "loss": np.array(
                        [np.nan if iv["loss"] is None else iv["loss"] for iv in res.intervals]
                    ),
                },
            }
        )
    return runs


def test_reproduction_figures_are_sized_per_panel_and_labelled(crossing, tmp_path):
    from PIL import Image

    from conformal_control.io.plotting import (
        plot_lambda_loss_rows,
        plot_lavg_vs_epsilon,
        plot_paths_grid,
    )

    runs = _paths_runs(crossing, 7)
    fig = plot_paths_grid(crossing, runs, tmp_path / "paths.png", title="Table")
    panels = [ax for ax in fig.axes if ax.axison]
    assert len(panels) == 7
    for ax in panels:
        assert ax.get_xlabel() == "x (m)" and ax.get_ylabel() == "y (m)"
    with Image.open(tmp_path / "paths.png") as im:
        width = im.size[0]
    assert width / 3 >= 400  # three panels per line, >= 400 px each
    fig = plot_lambda_loss_rows(runs, tmp_path / "ll.png", lam_unit="1/frame")
    lam_axes = [ax for ax in fig.axes if ax.get_ylabel().startswith("lambda")]
    loss_axes = [ax for ax in fig.axes if ax.get_ylabel().startswith("loss")]
    assert len(lam_axes) == len(loss_axes) == 7
    assert all(ax.get_xlabel() == "t (s)" and "(1/frame)" in ax.get_ylabel() for ax in lam_axes)
    assert all("dimensionless" in ax.get_ylabel() for ax in loss_axes)
    with Image.open(tmp_path / "ll.png") as im:
        assert im.size[0] / 3 >= 400
    pts = [{"series": "ours", "epsilon": e, "l_avg": e + 0.01} for e in (-0.2, 0.0, 0.2)]
    fig = plot_lavg_vs_epsilon(pts, tmp_path / "lavg.png")
    (ax,) = fig.axes
    assert "dimensionless" in ax.get_xlabel() and "dimensionless" in ax.get_ylabel()
