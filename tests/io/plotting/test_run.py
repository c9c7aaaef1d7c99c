"""Run plots: the reference image is decoded at about the size it is drawn at."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pytest
from PIL import Image

from conformal_control.io.plotting.run import plot_scene, reference_image


def _gradient(w: int, h: int) -> np.ndarray:
    x = np.linspace(0, 255, w)[None, :].repeat(h, 0)
    y = np.linspace(0, 255, h)[:, None].repeat(w, 1)
    return np.stack([x, y, 255 - x], axis=-1).astype(np.uint8)


@pytest.mark.parametrize("fmt", ["JPEG", "PNG"])
def test_reference_image_is_reduced_to_cover_the_display_size(tmp_path, fmt):
    full = _gradient(1600, 1200)
    path = tmp_path / f"ref.{fmt.lower()}"
    Image.fromarray(full).save(path, format=fmt)
    img, size = reference_image(path, (300, 200))
    assert size == (1600, 1200)
    h, w = img.shape[:2]
    assert w >= 300 and h >= 200  # still covers the axes: no detail is invented
    assert min(w / 300, h / 200) < 2  # but not much larger than it
    assert abs(w / h - 1600 / 1200) < 0.02  # aspect kept
    # the same picture: compare with the full image sampled at the reduced grid
    ys = ((np.arange(h) + 0.5) * 1200 / h).astype(int)
    xs = ((np.arange(w) + 0.5) * 1600 / w).astype(int)
    diff = np.abs(img[..., :3].astype(float) - full[ys][:, xs].astype(float))
    assert diff.mean() < 6


def test_reference_image_full_resolution_without_max_size(tmp_path):
    path = tmp_path / "ref.png"
    Image.fromarray(_gradient(64, 48)).save(path)
    img, size = reference_image(path)
    assert size == (64, 48) and img.shape == (48, 64, 3)
    # a small image asked for a larger display stays as it is
    img2, _ = reference_image(path, (640, 480))
    assert img2.shape == (48, 64, 3)


def test_scene_plot_draws_the_reduced_image_over_the_scene_extent(nexus4):
    from conformal_control.runs.episode import run_episode

    traj = run_episode(nexus4, "constant_velocity", max_frames=5).trajectory
    fig, ax = plt.subplots(figsize=(5, 3), dpi=100)
    plot_scene(ax, nexus4, traj, image_dpi=100)
    (im,) = ax.get_images()
    with Image.open(nexus4.image) as src:
        full_w, full_h = src.size
    arr = im.get_array()
    assert arr.shape[1] < full_w and arr.shape[0] < full_h  # reduced
    x0, x1, y1, y0 = im.get_extent()
    assert (x0, y0) == (0, 0)
    assert (x1, y1) == pytest.approx(tuple(nexus4.extent))  # drawn over the scene in metres
    plt.close(fig)
