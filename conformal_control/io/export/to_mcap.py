"""A run as an MCAP file that Foxglove opens (``conformal-control export RUN --format mcap``).

Every message is JSON with a JSON Schema (Foxglove's schemas for what the 3D panel draws,
flat schemas of our own for what the Plot panel plots), logged at the simulation time of
what it shows: nanoseconds since the start of the run, on the Unix epoch by default (the
run's ``t = 0`` shows as 1970-01-01 00:00:00 UTC; nothing in the file depends on when it
was written, so the same run gives the same file) or from the date and time given with
``--start-time`` (``start_time=``). Topics, for a single robot (``<r>`` = ``robot``) or for each
robot of a ``--robots`` run (``<r>`` = ``robot_0``, ``robot_1``, ...):

=========================  ==========================  ======================================
topic                      schema                      one message per
=========================  ==========================  ======================================
``/tf``                    ``foxglove.FrameTransform`` frame and robot: ``world`` -> ``<r>``
                                                       (heading = direction of motion)
``/<r>/pose``              ``foxglove.PoseInFrame``    frame: the robot's pose in ``world``
``/<r>/state``             ``...RobotState``           row of its ``trajectory.csv``: ``t``,
                                                       ``x``, ``y``, ``vx``, ``vy``, ``speed``,
                                                       ``d_min`` (+ ``status``, ``h_true_min``)
``/<r>/conformal``         ``...ConformalInterval``    row of its ``intervals.csv``: ``k``,
                                                       ``lambda``, ``loss`` (null when not
                                                       scored), ``loss_applied``, ``max_gap``,
                                                       ``n_sensed``, ``epsilon``
``/scene/robots``          ``foxglove.SceneUpdate``    frame: each robot's body and sensing
                                                       circle in its own frame (colour: green
                                                       free, orange constrained, red fallback
                                                       or contact, grey finished)
``/scene/pedestrians``     ``foxglove.SceneUpdate``    frame: every pedestrian present
``/scene/predictions``     ``foxglove.SceneUpdate``    interval (single robot): the predicted
                                                       paths of the agents sensed
``/scene/map``             ``foxglove.SceneUpdate``    once: start, goals, the whole path
=========================  ==========================  ======================================

The scene topics need the run's ``animation.npz`` (written by default); without it only
``/tf``, the poses, states and intervals are written. ``config.json`` is attached to the
file, and a metadata record ``conformal_control`` holds the scene, epsilon and lambda's
unit. Lengths are metres, times seconds, lambda in the scene's units as in the CSV files.
"""

from __future__ import annotations

import datetime
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ... import __version__
from ...core.exceptions import InputError
from . import foxglove as fg
from .destination import safe_output
from .reader import RunRecord, read_run

__all__ = ["write_mcap"]

GREEN = (0.2, 0.7, 0.3, 1.0)
ORANGE = (1.0, 0.6, 0.1, 1.0)
RED = (0.9, 0.15, 0.15, 1.0)
GREY = (0.55, 0.55, 0.55, 1.0)
BLUE = (0.25, 0.45, 0.85, 1.0)
PED = (0.35, 0.55, 0.8, 0.9)
SENSED = (0.95, 0.55, 0.1, 0.95)
PATH = (0.2, 0.2, 0.2, 0.6)
RING = (0.2, 0.6, 0.9, 0.5)
STATUS_RGBA = {0: GREEN, 1: ORANGE, 2: RED}
ROBOT_HEIGHT, PED_HEIGHT = 0.6, 1.7


def _num(v: float) -> float | None:
    """A JSON number: NaN and inf (no JSON value) become null."""
    return float(v) if math.isfinite(v) else None


def _headings(vx: np.ndarray, vy: np.ndarray) -> np.ndarray:
    """Direction of motion (rad); kept from the last move while standing (0 at first)."""
    yaw = np.zeros(vx.size)
    last = 0.0
    for i in range(vx.size):
        if math.hypot(vx[i], vy[i]) > 1e-9:
            last = math.atan2(vy[i], vx[i])
        yaw[i] = last
    return yaw


def _circle(radius: float, n: int = 64) -> list[tuple[float, float]]:
    a = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return list(zip((radius * np.cos(a)).tolist(), (radius * np.sin(a)).tolist(), strict=True))


class _Out:
    """The MCAP writer with one JSON channel per topic; messages are buffered and written
    in time order by :meth:`flush` (a topic's messages keep their order)."""

    def __init__(self, writer: Any, origin_ns: int = 0) -> None:
        self.writer = writer
        self.origin_ns = origin_ns
        self.schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}
        self.sequence: dict[str, int] = {}
        self.buffer: list[tuple[int, int, int, bytes]] = []

    def ns(self, t: float) -> int:
        """Simulation time (s since the start) as integer nanoseconds on the file's clock
        (:func:`write_mcap`'s ``start_time``; the Unix epoch by default)."""
        return self.origin_ns + round(t * 1e9)

    def channel(self, topic: str, schema: dict[str, Any], metadata: dict[str, str]) -> None:
        name = schema["title"]
        if name not in self.schemas:
            self.schemas[name] = self.writer.register_schema(
                name=name, encoding="jsonschema", data=json.dumps(schema).encode()
            )
        self.channels[topic] = self.writer.register_channel(
            topic=topic, message_encoding="json", schema_id=self.schemas[name], metadata=metadata
        )
        self.sequence[topic] = 0

    def write(self, topic: str, ns: int, message: dict[str, Any]) -> None:
        data = json.dumps(message, allow_nan=False, separators=(",", ":")).encode()
        self.buffer.append((ns, self.channels[topic], self.sequence[topic], data))
        self.sequence[topic] += 1

    def flush(self) -> None:
        self.buffer.sort(key=lambda m: m[0])  # stable: a topic's order is kept
        for ns, channel, seq, data in self.buffer:
            self.writer.add_message(
                channel_id=channel, log_time=ns, publish_time=ns, sequence=seq, data=data
            )
        self.buffer.clear()


def _robot_topics(out: _Out, rec: RunRecord) -> None:
    unit = {"lambda_unit": rec.lambda_unit, "length_unit": "m", "time_unit": "s"}
    for r in rec.robots:
        out.channel(f"/{r.name}/pose", fg.POSE_IN_FRAME, {})
        out.channel(f"/{r.name}/state", fg.ROBOT_STATE, unit)
        out.channel(f"/{r.name}/conformal", fg.INTERVAL, unit)
    for r in rec.robots:
        tr = r.trajectory
        yaw = _headings(tr["vx"], tr["vy"])
        for i in range(tr["t"].size):
            t = float(tr["t"][i])
            ns = out.ns(t)
            x, y = float(tr["x"][i]), float(tr["y"][i])
            out.write("/tf", ns, fg.frame_transform(ns, "world", r.name, x, y, float(yaw[i])))
            out.write(f"/{r.name}/pose", ns, fg.pose_in_frame(ns, "world", x, y, float(yaw[i])))
            vx, vy = float(tr["vx"][i]), float(tr["vy"][i])
            state: dict[str, Any] = {
                "frame": int(tr["frame"][i]),
                "t": t,
                "x": x,
                "y": y,
                "vx": vx,
                "vy": vy,
                "speed": math.hypot(vx, vy),
                "d_min": _num(float(tr["d_min"][i])),
            }
            if "d_min_robot" in tr:
                state["d_min_robot"] = _num(float(tr["d_min_robot"][i]))
            if r.status is not None and i < r.status.size:
                state["status"] = int(r.status[i])
            if r.h_true_min is not None and i < r.h_true_min.size:
                state["h_true_min"] = _num(float(r.h_true_min[i]))
            out.write(f"/{r.name}/state", ns, state)
        iv = r.intervals
        for j in range(iv["k"].size):
            t = float(iv["t"][j])
            msg: dict[str, Any] = {"k": int(iv["k"][j]), "t": t}
            for key in ("lambda", "loss", "loss_applied", "max_gap"):
                msg[key] = _num(float(iv[key][j]))
            for key in ("n_sensed", "n_steps"):
                msg[key] = int(iv[key][j])
            msg["epsilon"] = _num(rec.epsilon)
            out.write(f"/{r.name}/conformal", out.ns(t), msg)


def _scene_topics(out: _Out, rec: RunRecord) -> None:
    assert rec.frame_t is not None and rec.robots_xy is not None and rec.peds is not None
    out.channel("/scene/robots", fg.SCENE_UPDATE, {})
    out.channel("/scene/pedestrians", fg.SCENE_UPDATE, {})
    d_robot, d_ped = 2.0 * rec.robot_radius, 2.0 * rec.agent_radius
    ring = _circle(rec.sensing_radius) if math.isfinite(rec.sensing_radius) else []
    # which pedestrians the robot sensed during each frame (single robot: from predictions)
    sensed_from = [(t, set(cols.tolist())) for t, cols, _ in rec.predictions]
    s = 0
    for f, t in enumerate(rec.frame_t.tolist()):
        ns = out.ns(t)
        entities = []
        for m, r in enumerate(rec.robots):
            if rec.kind == "single":
                code = int(r.status[f]) if r.status is not None and f < r.status.size else 0
                rgba = STATUS_RGBA.get(code, RED)
            else:
                assert rec.active is not None and rec.contact is not None
                rgba = RED if rec.contact[f, m] else GREEN if rec.active[f, m] else GREY
            lines = [fg.line(ring, RING, thickness=0.04, loop=True)] if ring else []
            entities.append(
                fg.entity(
                    ns,
                    r.name,
                    r.name,
                    frame_locked=True,
                    cylinders=[fg.cylinder(0.0, 0.0, d_robot, ROBOT_HEIGHT, rgba)],
                    lines=lines,
                    texts=[fg.text(0.0, 0.0, ROBOT_HEIGHT + 0.4, r.name, rgba)]
                    if rec.kind == "multi"
                    else [],
                )
            )
        out.write("/scene/robots", ns, fg.scene_update(entities))
        while s + 1 < len(sensed_from) and sensed_from[s + 1][0] <= t:
            s += 1
        sensed = sensed_from[s][1] if sensed_from and sensed_from[s][0] <= t else set()
        p = rec.peds[f]
        present = np.flatnonzero(np.isfinite(p[:, 0]))
        cylinders = [
            fg.cylinder(
                float(p[c, 0]), float(p[c, 1]), d_ped, PED_HEIGHT, SENSED if c in sensed else PED
            )
            for c in present.tolist()
        ]
        meta = {"n_present": str(present.size)}
        if rec.ped_ids is not None:
            meta["ids"] = " ".join(str(int(rec.ped_ids[c])) for c in present)
        ped = fg.entity(ns, "world", "pedestrians", cylinders=cylinders, metadata=meta)
        out.write("/scene/pedestrians", ns, fg.scene_update([ped]))
    if rec.kind == "single":
        out.channel("/scene/predictions", fg.SCENE_UPDATE, {})
        for t, _cols, pred in rec.predictions:
            ns = out.ns(t)
            lines = []
            for path in pred:
                ok = np.isfinite(path[:, 0])
                if ok.sum() >= 2:
                    pts = [(float(a), float(b)) for a, b in path[ok]]
                    lines.append(fg.line(pts, SENSED, thickness=0.06, z=0.05))
            ent = fg.entity(ns, "world", "predictions", lines=lines)
            out.write("/scene/predictions", ns, fg.scene_update([ent]))


def _map_topic(out: _Out, rec: RunRecord) -> None:
    out.channel("/scene/map", fg.SCENE_UPDATE, {})
    entities = []
    for m, r in enumerate(rec.robots):
        tr = r.trajectory
        path = [(float(a), float(b)) for a, b in zip(tr["x"], tr["y"], strict=True)]
        goals = rec.goals[m] if m < len(rec.goals) else np.zeros((0, 2))
        x0, y0 = (float(v) for v in rec.starts[m])
        entities.append(
            fg.entity(
                out.ns(0.0),
                "world",
                f"{r.name}/map",
                lines=[fg.line(path, PATH, thickness=0.04, z=0.01)]
                + [
                    fg.line(
                        [(gx + a, gy + b) for a, b in _circle(rec.goal_radius, 32)],
                        BLUE,
                        loop=True,
                    )
                    for gx, gy in goals.tolist()
                ],
                spheres=[fg.sphere(x0, y0, 0.3, BLUE)],
                texts=[fg.text(gx, gy, 0.5, f"goal {r.name}", BLUE) for gx, gy in goals.tolist()],
            )
        )
    out.write("/scene/map", out.ns(0.0), fg.scene_update(entities))


def start_time_ns(start_time: datetime.datetime | str | None) -> int:
    """Nanoseconds since the Unix epoch of a run's ``t = 0`` on an exported file's clock:
    0 for None (the epoch: the same run, the same file), else the date and time given (an
    ISO 8601 text, ``2026-05-04T09:30:00Z``, or a ``datetime``; without a time zone, UTC).

    Parameters
    ----------
    start_time : datetime, str or None
        When the run's first frame is shown to have happened.

    Raises
    ------
    InputError
        For a text that is no ISO 8601 date and time.
    """
    if start_time is None:
        return 0
    if isinstance(start_time, str):
        try:
            start_time = datetime.datetime.fromisoformat(start_time.replace("Z", "+00:00"))
        except ValueError:
            raise InputError(
                f"start time {start_time!r} is not an ISO 8601 date and time, e.g. "
                "2026-05-04T09:30:00Z"
            ) from None
    if start_time.tzinfo is None:
        start_time = start_time.replace(tzinfo=datetime.timezone.utc)
    epoch = datetime.datetime(1970, 1, 1, tzinfo=datetime.timezone.utc)
    return (start_time - epoch) // datetime.timedelta(microseconds=1) * 1000


def write_mcap(
    run: str | Path | RunRecord,
    out: str | Path,
    *,
    start_time: datetime.datetime | str | None = None,
) -> Path:
    """Write a run directory (or a record read by :func:`read_run`) as an MCAP file.

    Parameters
    ----------
    run : path or RunRecord
    out : path
        The ``.mcap`` file to write (its folder is created), through
        :func:`~conformal_control.io.export.destination.safe_output`: never a file of the run
        directory but an earlier ``.mcap``, never a link or a device.
    start_time : datetime or str, optional
        The date and time the run's ``t = 0`` is shown at (:func:`start_time_ns`); None:
        the Unix epoch, so the file does not depend on when it was written.

    Returns
    -------
    Path
        ``out``.
    """
    try:
        from mcap.writer import CompressionType, Writer
    except ImportError as exc:  # pragma: no cover - mcap is a core dependency
        raise ImportError("export --format mcap needs the mcap package: pip install mcap") from exc
    rec = run if isinstance(run, RunRecord) else read_run(run)
    out = Path(out)
    with safe_output(out, inputs=(rec.path,), suffix=".mcap") as fh:
        writer = Writer(fh, compression=CompressionType.ZSTD)
        writer.start(profile="", library=f"conformal-control {__version__}")
        o = _Out(writer, start_time_ns(start_time))
        o.channel("/tf", fg.FRAME_TRANSFORM, {})
        _map_topic(o, rec)
        _robot_topics(o, rec)
        if rec.has_scene:
            _scene_topics(o, rec)
        o.flush()
        writer.add_metadata(
            "conformal_control",
            {
                "version": __version__,
                "kind": rec.kind,
                "scene": rec.scene,
                "epsilon": repr(rec.epsilon),
                "lambda_unit": rec.lambda_unit,
                "robots": " ".join(r.name for r in rec.robots),
                "scene_topics": "yes" if rec.has_scene else "no (no animation.npz)",
            },
        )
        writer.add_attachment(
            create_time=0,
            log_time=0,
            name="config.json",
            media_type="application/json",
            data=rec.config_bytes,
        )
        writer.finish()  # type: ignore[no-untyped-call]  # mcap's Writer.finish is unannotated
    return out
