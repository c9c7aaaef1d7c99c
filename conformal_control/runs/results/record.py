"""A compact record of an episode for ``conformal-control animate`` (``animation.npz``).

The run directory's CSV files hold the robot and the interval traces; the animation also
needs what the robot saw: the pedestrians' positions, the agents sensed at each sampling
time with their predicted trajectories, and the state of the constraints. The recorder
collects these while the loop runs (through its ``on_interval`` hook) at frame resolution,
in float32, so a nexus_4 run's record is about 100 kB.

Keys of the record (``F`` logged frames, ``M`` pedestrians present during the run, ``K``
intervals, ``N`` most agents sensed in one interval, ``H`` frames per interval):

==================  ================  ===============================================
key                 shape             content
==================  ================  ===============================================
``frame``           (F,)              video frame numbers of the logged frames
``t``               (F,)              time since the start (s)
``robot``           (F, 2)            robot position (m)
``peds``            (F, M, 2)         pedestrian positions (m), NaN when absent
``ped_ids``         (M,)              their track ids
``status``          (F,)              0 free, 1 constraint active, 2 QP infeasible
                                      at lambda_k (fallback) during the frame
``h_true_min``      (F,)              smallest barrier value with the TRUE positions of
                                      the agents within the sensing radius (< 0: the
                                      safe set is left); NaN when none is sensed
``k_start``         (K,)              index into ``frame`` where interval k starts
``pred``            (K, N, H + 1, 2)  predicted positions of the sensed agents from the
                                      interval's start (NaN padded)
``pred_cols``       (K, N)            their columns in ``peds`` (-1 padded)
``lam``, ``loss``   (K,)              lambda_k (scene units) and l_k (NaN if unscored)
==================  ================  ===============================================

plus scalars and strings: ``epsilon``, ``sensing_radius``, ``collision_distance``,
``goal_radius``, ``fps``, ``start``, ``goals``, ``extent``, ``image``, ``scene``,
``lambda_unit``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...core.loop import IntervalLog
from ...data.scene import Scene
from ...families.cbf.roles import Barrier

__all__ = ["AnimationRecorder"]

_STATUS = {"unconstrained": 0, "optimal": 1}


class AnimationRecorder:
    """Collect the animation record of one episode.

    Parameters
    ----------
    scene : Scene
    family : ConformalCBFController
        The decision family, read through its ``interval_record()`` after each interval.
    barrier : Barrier
        Used to evaluate the true barrier values per frame.
    tau_frames, substeps : int
        Frames per interval and control instants per frame.
    sensing_radius : float
        Sensor range (m).
    """

    def __init__(
        self,
        scene: Scene,
        family: Any,
        barrier: Barrier,
        tau_frames: int,
        substeps: int,
        sensing_radius: float,
    ) -> None:
        self.scene = scene
        self.family = family
        self.barrier = barrier
        self.tau_frames = int(tau_frames)
        self.substeps = int(substeps)
        self.sensing_radius = float(sensing_radius)
        self._preds: list[tuple[np.ndarray, np.ndarray]] = []
        self._status: list[np.ndarray] = []

    def __call__(self, log: IntervalLog) -> None:
        """The loop's ``on_interval`` hook: keep the interval's predictions and status."""
        rec = self.family.interval_record()
        codes = np.array([_STATUS.get(st, 2) for st in rec.status], dtype=np.int8)
        self.add_interval(rec.ids, rec.x_pred, codes)

    def add_interval(self, ids: np.ndarray, x_pred: np.ndarray, codes: np.ndarray) -> None:
        """Keep an interval: the sensed agents' ``ids``, their predicted positions at the
        interval's control instants ``x_pred`` (S, N, 2) and the filter's status code of
        each instant ``codes`` (S,): 0 free, 1 constraint active, 2 fallback."""
        s = self.substeps
        self._preds.append((np.asarray(ids), np.asarray(x_pred[::s], dtype=np.float32)))
        n_frames = -(-codes.size // s)
        if n_frames * s != codes.size:  # a last, partial frame: padded with "free"
            padded = np.zeros(n_frames * s, dtype=np.int8)
            padded[: codes.size] = codes
            codes = padded
        codes = np.asarray(codes, dtype=np.int8)
        self._status.append(codes.reshape(n_frames, s).max(axis=1) if n_frames else codes)

    def finish(
        self,
        trajectory: dict[str, np.ndarray],
        intervals: list[dict[str, Any]],
        extra: dict[str, Any],
    ) -> dict[str, Any]:
        """Assemble the record once the episode is over."""
        sc = self.scene
        frames = np.asarray(trajectory["frame"]) - sc.first_frame
        n = frames.size
        robot = np.column_stack([trajectory["x"], trajectory["y"]])
        if n:  # the frames of the episode, the agents seen over them (read sparsely)
            lo, hi = int(frames.min()), int(frames.max()) + 1
            seen = sc.tracks.overlapping(lo, hi)
            win = sc.tracks.dense(lo, hi, seen)[frames - lo]
        else:
            seen, win = np.zeros(0, dtype=np.int64), np.zeros((0, 0, 2))
        present = np.isfinite(win[..., 0]).any(axis=0)
        cols = np.flatnonzero(present)
        peds = win[:, cols].astype(np.float32)
        ped_ids = sc.agent_ids[seen[cols]]
        col_of = {int(a): i for i, a in enumerate(ped_ids)}
        status = np.zeros(n, dtype=np.int8)
        if self._status:
            st = np.concatenate(self._status)[:n]
            status[: st.size] = st
        # the barrier with the true positions of the agents present and within the sensing
        # radius, every frame at once (element-wise, so the values of a per-frame call)
        p = win[:, cols]
        ok = np.isfinite(p[..., 0])
        near = ok & (
            np.hypot(p[..., 0] - robot[:, :1], p[..., 1] - robot[:, 1:]) <= self.sensing_radius
        )
        h_min = np.full(n, np.nan)
        rows, agents = np.nonzero(near)  # row-major: the pairs of a frame are consecutive
        if rows.size:
            h = self.barrier.evaluate(robot[rows], p[rows, agents])[0]
            first = np.flatnonzero(np.diff(rows, prepend=-1))
            h_min[rows[first]] = np.minimum.reduceat(h, first)
        k = len(self._preds)
        n_max = max((ids.size for ids, _ in self._preds), default=0)
        pred = np.full((k, n_max, self.tau_frames + 1, 2), np.nan, dtype=np.float32)
        pred_cols = np.full((k, n_max), -1, dtype=np.int32)
        kept = [j for j, (ids, xp) in enumerate(self._preds) if ids.size and xp.size]
        for j in kept:
            ids, xp = self._preds[j]
            m = min(xp.shape[0], self.tau_frames + 1)
            pred[j, : ids.size, :m] = xp[:m].transpose(1, 0, 2)
        if kept:  # every interval's columns in one pass
            sizes = [self._preds[j][0].size for j in kept]
            all_ids = np.concatenate([self._preds[j][0] for j in kept]).tolist()
            pred_cols[np.repeat(kept, sizes), np.concatenate([np.arange(z) for z in sizes])] = [
                col_of.get(int(a), -1) for a in all_ids
            ]
        k_start = np.minimum(np.arange(k) * self.tau_frames, max(n - 1, 0))
        lam = np.array([iv["lambda"] for iv in intervals], dtype=float)
        loss = np.array(
            [np.nan if iv["loss"] is None else iv["loss"] for iv in intervals], dtype=float
        )
        return {
            "frame": np.asarray(trajectory["frame"]),
            "t": np.asarray(trajectory["t"], dtype=float),
            "robot": robot.astype(np.float32),
            "peds": peds,
            "ped_ids": ped_ids,
            "status": status,
            "h_true_min": h_min.astype(np.float32),
            "k_start": k_start,
            "pred": pred,
            "pred_cols": pred_cols,
            "lam": lam,
            "loss": loss,
            "sensing_radius": self.sensing_radius,
            "collision_distance": sc.collision_distance,
            "goal_radius": sc.goal_radius,
            "fps": float(sc.fps),
            "start": np.asarray(sc.start, dtype=float),
            "goals": np.asarray(sc.goals, dtype=float),
            "extent": np.asarray(sc.extent if sc.extent is not None else (np.nan, np.nan)),
            "image": str(sc.image) if sc.image is not None else "",
            "scene": sc.name,
            **extra,
        }
