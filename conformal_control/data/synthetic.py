"""The built-in scene: seeded synthetic pedestrian flows crossing the robot's path.

Needs no downloaded data. The area is 30 m x 16 m (image-like coordinates: x to the
right, y down). The robot crosses it from (2, 8) to (28, 8). Pedestrians arrive as
Poisson processes in three flows: two crossing the robot's path (walking down and up
through the band 8 m <= x <= 22 m) and one walking against the robot. Each walks at a
preferred speed ~ N(1.3, 0.15^2) m/s with an Ornstein-Uhlenbeck wobble of its heading
and speed, so constant-velocity predictions are good but not perfect: the prediction
errors the conformal controller must adapt to are real, not injected.
"""

from __future__ import annotations

import numpy as np

from .scene import Scene, scene_from_tracks
from .tracks import Tracks
from .units import SI

__all__ = ["SYNTHETIC_DEFAULTS", "crossing_scene"]

#: Default controller parameters for the built-in scene (SI units).
SYNTHETIC_DEFAULTS: dict[str, float] = {
    "a": 2.0,  # 1/s
    "K_acc": 10.0,  # 1/s
    "K_rep": 0.5,  # m^2
    "K_att": 1.0,  # 1/s
    "rho0": 5.0,  # m
    "tau": 0.4,  # s
    "eta": 2.0,  # 1/s
    "epsilon": -0.1,
    "loss_scale": 1.0,  # 1/s
}

_W, _H = 30.0, 16.0


def _walk(
    rng: np.random.Generator, p0: np.ndarray, heading: float, n: int, dt: float
) -> np.ndarray:
    speed0 = max(0.6, rng.normal(1.3, 0.15))
    th = np.empty(n)
    sp = np.empty(n)
    th_dev, sp_dev = 0.0, 0.0
    theta_rate, sigma_th, sigma_sp = 0.5, 0.35, 0.25  # OU reversion (1/s) and noise scales
    for i in range(n):
        th_dev += -theta_rate * th_dev * dt + sigma_th * np.sqrt(dt) * rng.normal()
        sp_dev += -theta_rate * sp_dev * dt + sigma_sp * np.sqrt(dt) * rng.normal()
        th[i] = heading + th_dev
        sp[i] = max(0.2, speed0 + sp_dev)
    vel = np.column_stack([sp * np.cos(th), sp * np.sin(th)])
    return p0 + np.vstack([np.zeros(2), np.cumsum(vel[:-1] * dt, axis=0)])


def crossing_scene(
    seed: int = 0,
    duration: float = 60.0,
    fps: float = 10.0,
    rate: float = 0.3,
    history: float = 12.0,
) -> Scene:
    """Generate the built-in crossing scene.

    Parameters
    ----------
    seed : int
        Seed of the pedestrian generator (the scene is a pure function of its arguments).
    duration : float
        Seconds of pedestrian data after the robot starts.
    fps : float
        Frame rate of the generated data.
    rate : float
        Arrivals per second in each of the three flows.
    history : float
        Seconds of data before the robot starts (warm-up and predictor history).
    """
    if not (duration > 0 and fps > 0 and rate >= 0 and history >= 0):
        raise ValueError("duration and fps must be > 0, rate and history >= 0")
    rng = np.random.default_rng(seed)
    dt = 1.0 / fps
    n_total = round((duration + history) * fps)
    flows = [
        # (spawn position sampler, heading)
        (lambda: np.array([rng.uniform(8.0, 22.0), -0.5]), np.pi / 2),
        (lambda: np.array([rng.uniform(8.0, 22.0), _H + 0.5]), -np.pi / 2),
        (lambda: np.array([_W + 0.5, rng.uniform(5.0, 11.0)]), np.pi),
    ]
    tracks: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    tid = 0
    # start spawning well before the window so the area is populated at frame 0
    warm = 25.0
    for spawn, heading in flows:
        t = -warm + rng.exponential(1.0 / rate) if rate > 0 else np.inf
        while t < duration + history:
            f0 = int(np.floor(t * fps))
            n = int(40.0 * fps)
            xy = _walk(rng, spawn(), heading, n, dt)
            frames = np.arange(f0, f0 + n)
            inside = (xy[:, 0] > -1) & (xy[:, 0] < _W + 1) & (xy[:, 1] > -1) & (xy[:, 1] < _H + 1)
            # keep the first contiguous run inside the area and within the data window
            keep = inside & (frames >= 0) & (frames < n_total)
            if keep.any():
                idx = np.flatnonzero(keep)
                run_end = idx[0] + np.argmin(np.append(keep[idx[0] :], False))
                sel = slice(idx[0], run_end)
                tracks[tid] = (frames[sel], xy[sel])
                tid += 1
            t += rng.exponential(1.0 / rate)
    data = Tracks(
        fps=fps,
        tracks=tracks,
        source=f"synthetic crossing (seed={seed})",
        meta={"generator": "crossing_scene", "seed": seed, "rate": rate},
    )
    start_frame = round(history * fps)
    return scene_from_tracks(
        data,
        name="crossing",
        start=np.array([2.0, _H / 2]),
        goals=np.array([[_W - 2.0, _H / 2]]),
        start_frame=start_frame,
        v_max=2.0,
        history_frames=start_frame,
        last_frame=n_total - 1,
        units=SI,
        defaults=dict(SYNTHETIC_DEFAULTS),
        extent=(_W, _H),
        robot_radius=0.4,
        agent_radius=0.3,
        goal_radius=0.5,
    )
