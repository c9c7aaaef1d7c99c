"""The sweep's summary plot: axes chosen from what varies, per-run plots off by default."""

from __future__ import annotations

from pathlib import Path

from conformal_control.cli import main
from conformal_control.sweep.summary import summary_axes, write_summary_plot


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
