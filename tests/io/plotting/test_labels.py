"""place_labels: no two labels overlap, none covers a point, all inside the axes, each
joined to its point when moved away; the benchmark frontier names every method."""

from __future__ import annotations

import io

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pytest

from conformal_control.io.plotting.labels import place_labels


def _boxes(fig, texts) -> np.ndarray:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    if not hasattr(fig.canvas, "get_renderer"):  # closed by pyplot
        FigureCanvasAgg(fig)
    renderer = fig.canvas.get_renderer()
    return np.array([t.get_window_extent(renderer).extents for t in texts])


def _check_layout(fig, ax, x, y, placed, marker_px: float = 12.0) -> None:
    fig.savefig(io.BytesIO(), format="png", dpi=fig.dpi)  # the layout as saved
    texts = [t for t in placed.texts if t is not None]
    boxes = _boxes(fig, texts)
    frame = ax.get_window_extent(fig.canvas.get_renderer()).extents
    for i in range(len(boxes)):
        a = boxes[i]
        assert (a[:2] >= frame[:2] - 0.5).all() and (a[2:] <= frame[2:] + 0.5).all(), "outside"
        for j in range(i + 1, len(boxes)):
            b = boxes[j]
            overlap = a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]
            assert not overlap, (texts[i].get_text(), texts[j].get_text())
    pts = ax.transData.transform(np.column_stack([x, y]))
    h = marker_px / 2
    for a, t in zip(boxes, texts, strict=True):
        covered = (pts[:, 0] + h > a[0]) & (pts[:, 0] - h < a[2])
        covered &= (pts[:, 1] + h > a[1]) & (pts[:, 1] - h < a[3])
        assert not covered.any(), f"{t.get_text()} covers a point"


@pytest.mark.parametrize("seed", range(5))
def test_clustered_points_get_labels_that_do_not_overlap(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = 16
    x = np.r_[rng.normal(7.7, 0.1, n - 3), 8.2, 8.3, 10.8]  # a tight cluster and a few apart
    y = np.r_[rng.normal(23, 2, n - 3), 61, 77, 2]
    x[1], y[1] = x[0], y[0]  # two points that coincide
    names = [f"method_{i}[eps=-0.{i:02d}]" for i in range(n)]
    fig, ax = plt.subplots(figsize=(8, 6), constrained_layout=True)
    ax.errorbar(x, y, xerr=0.1, yerr=3, fmt="o", capsize=2)
    xlim, ylim = ax.get_xlim(), ax.get_ylim()
    placed = place_labels(ax, x, y, names, fontsize=7)
    assert placed.unplaced == []
    assert ax.get_xlim() == xlim and ax.get_ylim() == ylim  # leaders do not rescale
    _check_layout(fig, ax, x, y, placed)
    # a label moved away from its point is joined to it: one leader per such label
    pts = ax.transData.transform(np.column_stack([x, y]))
    ends = [ax.transData.transform(np.column_stack(ln.get_data()))[-1] for ln in placed.leaders]
    for end in ends:
        assert np.min(np.hypot(*(pts - end).T)) < 1e-6  # every leader ends on a point
    plt.close(fig)


def test_a_label_that_cannot_fit_is_reported_not_drawn_on_top() -> None:
    fig, ax = plt.subplots(figsize=(1.2, 1.0))
    x, y = np.array([0.5, 0.5]), np.array([0.5, 0.52])
    placed = place_labels(ax, x, y, ["a very long label indeed", "another very long label"])
    assert placed.unplaced == [0, 1] and placed.texts == [None, None]
    assert not ax.texts  # nothing left half-placed
    with pytest.raises(ValueError, match="one text per point"):
        place_labels(ax, [0.0], [0.0], ["a", "b"])
    plt.close(fig)


def test_the_benchmark_frontier_names_every_method_without_overlap(tmp_path, monkeypatch) -> None:
    """bench's frontier figure: every shown method labelled, Pareto members in bold."""
    import conformal_control.experiments.bench.report as report

    captured = {}
    real = report._frontier

    def spy(v, path, title):
        orig_savefig = plt.Figure.savefig

        def keep(fig, *a, **k):
            captured["fig"] = fig
            return orig_savefig(fig, *a, **k)

        monkeypatch.setattr(plt.Figure, "savefig", keep)
        real(v, path, title)

    from conformal_control.experiments.bench.stats import bootstrap_mean

    class Summary:
        def __init__(self, method: str, reached: list[float], frames: list[float]) -> None:
            self.method, self.label = method, ""
            self.estimates = {
                "reached": bootstrap_mean(reached, seed=0),
                "collision frames": bootstrap_mean(frames, seed=0),
            }

    rng = np.random.default_rng(1)
    shown = [
        Summary(m, list(rng.random(40) < p), list(rng.poisson(f, 40)))
        for m, p, f in [
            ("nolearn", 0.77, 3.4),
            ("fixed[lambda=-5/s]", 0.76, 3.3),
            ("conformal[eps=-0.05]", 0.76, 3.3),
            ("inflated[margin=0.1m]", 0.78, 3.9),
            ("acp[alpha=0.2]", 0.7, 4.5),
        ]
    ]

    class View:
        pass

    v = View()
    v.shown = shown
    spy(v, tmp_path / "frontier.png", "test")
    fig = captured["fig"]
    ax = fig.axes[0]
    labels = {t.get_text(): t for t in ax.texts}
    assert {k.rstrip(" *") for k in labels} == {s.method for s in shown}
    front = report._pareto(
        [(-s.estimates["reached"].mean, s.estimates["collision frames"].mean) for s in shown]
    )
    for s, on in zip(shown, front, strict=True):
        t = labels[s.method + (" *" if on else "")]
        assert (t.get_fontweight() == "bold") == on
    assert any(front)
    boxes = _boxes(fig, list(ax.texts))
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            a, b = boxes[i], boxes[j]
            assert not (a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3])
    assert (tmp_path / "frontier.png").stat().st_size > 10_000
    plt.close(fig)
