"""The built-in scene: seeded synthetic pedestrian flows crossing the robot's path.

Needs no downloaded data. The area is 30 m x 16 m (image-like coordinates: x to the
right, y down). The robot crosses it from (2, 8) to (28, 8). Pedestrians arrive as
Poisson processes in three flows: two crossing the robot's path (walking down and up
through the band 8 m <= x <= 22 m) and one walking against the robot. Each walks at a
preferred speed ~ N(1.3, 0.15^2) m/s with an Ornstein-Uhlenbeck wobble of its heading
and speed, so constant-velocity predictions are good but not perfect: the prediction
errors the conformal controller must adapt to are real, not injected.

The walks are integrated for every pedestrian at once (one numpy step per frame); the
output is bit-identical, seed for seed, to the original per-pedestrian loop, which
``tests/data/test_synthetic.py`` keeps as its reference (``benchmarks/bench_synthetic.py``
times both).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .scene import Scene, scene_from_tracks
from .tracks import Tracks
from .units import SI

__all__ = ["SYNTHETIC_DEFAULTS", "crossing_scene", "crossing_tracks"]

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


#: Ornstein-Uhlenbeck reversion rate (1/s) and noise scales of heading (rad) and speed (m/s).
_THETA_RATE, _SIGMA_TH, _SIGMA_SP = 0.5, 0.35, 0.25
#: Length of every generated walk (s) and warm-up before the data window (s).
_WALK_SECONDS, _WARM = 40.0, 25.0


def _walks(
    p0: np.ndarray, heading: np.ndarray, speed0: np.ndarray, z: np.ndarray, dt: float
) -> np.ndarray:
    """Positions of P walks of n samples, shape (P, n, 2), from their draws.

    ``z[:, i]`` holds the (heading, speed) normal draws of step ``i``. The OU recursion is
    stepped for all walks at once (one numpy operation per time step instead of one
    Python step per walk per time step), with exactly the floating-point operations of a
    scalar loop, so every seed gives the same bits as before vectorisation.
    """
    n_walks, n = z.shape[:2]
    a_th = _SIGMA_TH * np.sqrt(dt)
    a_sp = _SIGMA_SP * np.sqrt(dt)
    th = np.empty((n_walks, n))
    sp = np.empty((n_walks, n))
    th_dev = np.zeros(n_walks)
    sp_dev = np.zeros(n_walks)
    for i in range(n):
        th_dev = th_dev + (-_THETA_RATE * th_dev * dt + a_th * z[:, i, 0])
        sp_dev = sp_dev + (-_THETA_RATE * sp_dev * dt + a_sp * z[:, i, 1])
        th[:, i] = heading + th_dev
        sp[:, i] = np.maximum(0.2, speed0 + sp_dev)
    # trigonometry row by row: each row is evaluated exactly as a standalone walk was
    vel = np.empty((n_walks, n, 2))
    for j in range(n_walks):
        vel[j, :, 0] = sp[j] * np.cos(th[j])
        vel[j, :, 1] = sp[j] * np.sin(th[j])
    xy = np.empty((n_walks, n, 2))
    xy[:, 0] = p0
    xy[:, 1:] = p0[:, None, :] + np.cumsum(vel[:, :-1] * dt, axis=1)
    return xy


def crossing_tracks(
    seed: int = 0,
    duration: float = 60.0,
    fps: float = 10.0,
    rate: float = 0.3,
    history: float = 12.0,
) -> Tracks:
    """The pedestrian tracks of the crossing scene (arguments of :func:`crossing_scene`).

    The random draws of each pedestrian are taken in the order the generator has always
    used (spawn position, preferred speed, 2 normals per step, next arrival), then all
    walks are integrated together (:func:`_walks`).

    Parameters
    ----------
    seed : int
        Seed of the pedestrian generator.
    duration : float
        Seconds of pedestrian data after the robot starts.
    fps : float
        Frame rate of the generated data.
    rate : float
        Arrivals per second in each of the three flows.
    history : float
        Seconds of data before the robot starts.
    """
    if not (duration > 0 and fps > 0 and rate >= 0 and history >= 0):
        raise ValueError("duration and fps must be > 0, rate and history >= 0")
    rng = np.random.default_rng(seed)
    dt = 1.0 / fps
    n_total = round((duration + history) * fps)
    n = int(_WALK_SECONDS * fps)
    flows: list[tuple[Callable[[], np.ndarray], float]] = [
        # (spawn position sampler, heading)
        (lambda: np.array([rng.uniform(8.0, 22.0), -0.5]), np.pi / 2),
        (lambda: np.array([rng.uniform(8.0, 22.0), _H + 0.5]), -np.pi / 2),
        (lambda: np.array([_W + 0.5, rng.uniform(5.0, 11.0)]), np.pi),
    ]
    f0s: list[int] = []
    p0s: list[np.ndarray] = []
    headings: list[float] = []
    speeds: list[float] = []
    draws: list[np.ndarray] = []
    # start spawning well before the window so the area is populated at frame 0
    for spawn, heading in flows:
        t = -_WARM + rng.exponential(1.0 / rate) if rate > 0 else np.inf
        while t < duration + history:
            f0s.append(int(np.floor(t * fps)))
            p0s.append(spawn())
            headings.append(heading)
            speeds.append(max(0.6, rng.normal(1.3, 0.15)))
            draws.append(rng.normal(size=(n, 2)))  # (heading, speed) draws per step
            t += rng.exponential(1.0 / rate)
    meta = {"generator": "crossing_scene", "seed": seed, "rate": rate}
    source = f"synthetic crossing (seed={seed})"
    if not f0s:
        return Tracks(fps=fps, tracks={}, source=source, meta=meta)
    xy = _walks(np.array(p0s), np.array(headings), np.array(speeds), np.stack(draws), dt)
    frames = np.array(f0s)[:, None] + np.arange(n)
    inside = (xy[..., 0] > -1) & (xy[..., 0] < _W + 1) & (xy[..., 1] > -1) & (xy[..., 1] < _H + 1)
    # keep the first contiguous run inside the area and within the data window
    keep = inside & (frames >= 0) & (frames < n_total)
    tracks: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for j in np.flatnonzero(keep.any(axis=1)):
        k = keep[j]
        first = int(np.argmax(k))
        end = first + int(np.argmin(np.append(k[first:], False)))
        tracks[len(tracks)] = (frames[j, first:end].copy(), xy[j, first:end].copy())
    return Tracks(fps=fps, tracks=tracks, source=source, meta=meta)


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
    data = crossing_tracks(seed, duration, fps, rate, history)
    n_total = round((duration + history) * fps)
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
