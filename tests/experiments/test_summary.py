"""The sweep's summary plot: axes chosen from what varies, per-run plots off by default."""

from __future__ import annotations

from pathlib import Path

from conformal_control.cli import main
from conformal_control.experiments.summary import summary_axes, write_summary_plot


def row(**kw) -> dict:
    return {"status": "ok", "predictor": "constant_velocity", "learn": True, "seed": 0, **kw}


def test_summary_axes() -> None:
    rows = [
        row(**{"param.eta": e, "param.epsilon": x, "seed": s})
        for e in (0.1, 1)
        for x in (-0.1, 0.1)
        for s in (0, 1)
    ]
    assert summary_axes(rows) == ("param.epsilon", "param.eta")
    rows = [row(**{"param.tau": t, "predictor": p}) for t in (4, 8) for p in ("a", "b")]
    assert summary_axes(rows) == ("param.tau", "predictor")
    assert summary_axes([row(seed=0), row(seed=1)]) == ("seed", None)
    assert summary_axes([row(label="a"), row(label="b")]) == (None, None)  # nothing numeric
    many = [row(**{"param.epsilon": x / 10, "param.eta": x}) for x in range(-3, 4)]
    assert summary_axes(many) == ("param.epsilon", None)  # 7 eta values: too many lines


def test_no_summary_plot_without_a_numeric_axis(tmp_path: Path) -> None:
    path, note = write_summary_plot([row(label="a"), row(label="b")], tmp_path / "s.png")
    assert path is None and "no numeric parameter varies" in note
    path, note = write_summary_plot([{"status": "failed"}], tmp_path / "s.png")
    assert path is None and "no run finished ok" in note
    assert not (tmp_path / "s.png").exists()


def test_cli_sweep_writes_a_summary_not_per_run_plots(tmp_path: Path, capsys) -> None:
    argv = [
        "sweep",
        "--scene",
        "crossing",
        "--set",
        "frames=10",
        "--executor",
        "serial",
        "--progress",
        "off",
        "--grid",
        "epsilon=-0.1,0.1",
    ]
    out = tmp_path / "sw"
    assert main([*argv, "--out", str(out)]) == 0
    assert f"summary plot: {out / 'summary.png'}" in capsys.readouterr().out
    assert (out / "summary.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    runs = sorted((out / "runs").iterdir())
    assert len(runs) == 2 and all((r / "metrics.json").exists() for r in runs)
    assert not any((r / "plot.png").exists() for r in runs)  # per-run plots off by default
    out2 = tmp_path / "sw2"  # one run is enough to see --plots at work
    one = [*argv[:-1], "epsilon=-0.1", "--plots", "--no-summary-plot", "--out", str(out2)]
    assert main(one) == 0
    (run,) = (out2 / "runs").iterdir()
    assert (run / "plot.png").exists() and (run / "guarantee.png").exists()
    assert not (out2 / "summary.png").exists()


def test_summary_plot_averages_nothing_it_does_not_say(tmp_path: Path) -> None:
    """A sweep's results hold metrics named like parameters (lambda_min, epsilon, eta):
    the summary neither averages over them nor over the x axis or its lines."""
    from matplotlib.figure import Figure

    import conformal_control.io.plotting.sweep as plotting_sweep

    rows = [
        row(
            scene="nexus_4",
            **{"param.epsilon": e, "param.eta": eta},
            epsilon=e,  # the metrics copy the values used ...
            eta=30 * eta,  # ... in SI
            lambda_min=-0.7 - i,  # a metric that differs in every run
            t_goal=8.3,
            n_collide=0,
            d_min=1.23,
            l_avg=e + 0.05,
        )
        for i, (e, eta) in enumerate((e, eta) for e in (-0.3, -0.25, -0.2) for eta in (0.5, 1))
    ]
    captured: list[Figure] = []
    real = plotting_sweep.plot_sweep

    def spy(*a, **k):
        fig = real(*a, **k)
        captured.append(fig)
        return fig

    import pytest

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(plotting_sweep, "plot_sweep", spy)
        path, note = write_summary_plot(rows, tmp_path / "summary.png")
    assert path is not None and "epsilon on the x axis, one line per eta" in note
    (fig,) = captured
    title = fig.get_suptitle()
    assert title.endswith("\neach point: one run"), title
    assert "lambda_min" not in title and "averaged" not in title
    assert fig.get_supxlabel().startswith("epsilon")
    labels = [ln.get_label() for ln in fig.axes[0].get_lines()]
    assert labels == ["eta = 0.5", "eta = 1"]
