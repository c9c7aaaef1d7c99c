"""A run as ROS 2 messages: one MCAP file (``export RUN --schema ros2``) or a bag folder
(``export RUN --format ros2-bag``), for ``ros2 bag play``, rqt and ROS-typed Foxglove panels.

Every message is a standard ROS 2 type, CDR-encoded, with its ``ros2msg`` definition in the
file (written with ``rosbags``' typestore: the ``ros`` extra), stamped (log time and header)
from the run's clock: nanoseconds since the start of the run, as in the Foxglove export.
Topics, for a single robot (``<r>`` = ``robot``) or each robot of a ``--robots`` run
(``<r>`` = ``robot_0``, ...), frame ``world``:

=========================  =====================================  =============================
topic                      type                                   one message per
=========================  =====================================  =============================
``/tf``                    ``tf2_msgs/msg/TFMessage``             frame: ``world`` -> ``<r>``
                                                                  (heading = direction of
                                                                  motion)
``/<r>/pose``              ``geometry_msgs/msg/PoseStamped``      frame: the robot's pose
``/<r>/cmd_vel``           ``geometry_msgs/msg/Twist``            frame: the robot's velocity
                                                                  (``trajectory.csv``'s
                                                                  ``vx``, ``vy``) in its body
                                                                  frame: linear.x the speed,
                                                                  angular.z the heading's rate
``/<r>/distance``          ``std_msgs/msg/Float64``               frame: ``d_min`` (m)
``/<r>/lambda``            ``std_msgs/msg/Float64``               interval: lambda (scene units)
``/<r>/loss``              ``std_msgs/msg/Float64``               scored interval: its loss
``/scene/robots``          ``visualization_msgs/msg/MarkerArray`` frame: a cylinder per robot
``/scene/pedestrians``     ``visualization_msgs/msg/MarkerArray`` frame: a cylinder per
                                                                  pedestrian present (marker id
                                                                  = the pedestrian's id),
                                                                  after a DELETEALL
``/scene/predictions``     ``visualization_msgs/msg/MarkerArray`` interval (single robot): a
                                                                  line strip per predicted path
``/scene/map``             ``visualization_msgs/msg/MarkerArray`` once: start, goals, path
=========================  =====================================  =============================

The scene topics need the run's ``animation.npz`` (as the Foxglove export). The MCAP file
also holds ``config.json`` as an attachment and a metadata record ``conformal_control``;
the bag folder has no place for them.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np

from ... import __version__
from .destination import check_destination, safe_output
from .reader import RunRecord, read_run

__all__ = ["ros2_recording", "write_ros2_bag", "write_ros2_mcap"]

ROBOT_RGBA = (0.2, 0.7, 0.3, 1.0)
PED_RGBA = (0.35, 0.55, 0.8, 0.9)
PRED_RGBA = (0.95, 0.55, 0.1, 0.95)
MAP_RGBA = (0.25, 0.45, 0.85, 1.0)
ROBOT_HEIGHT, PED_HEIGHT = 0.6, 1.7


def _ns(t: float) -> int:
    return round(t * 1e9)


def _headings(vx: np.ndarray, vy: np.ndarray) -> np.ndarray:
    """Direction of motion (rad), kept from the last move while standing (0 at first)."""
    yaw = np.arctan2(vy, vx)
    moving = np.hypot(vx, vy) > 1e-9
    idx = np.where(moving, np.arange(vx.size), -1)
    np.maximum.accumulate(idx, out=idx)
    out: np.ndarray = np.where(idx >= 0, yaw[np.maximum(idx, 0)], 0.0)
    return out


def ros2_recording(rec: RunRecord) -> object:
    """The run's messages (a :class:`~conformal_control.io.ros2.writer.Recording`).

    Parameters
    ----------
    rec : RunRecord
        A run read by :func:`~conformal_control.io.export.reader.read_run`.
    """
    from ..ros2 import writer as w
    from ..ros2.types import FLOAT64, TF_MESSAGE, TWIST, typestore

    t = typestore().types
    out = w.Recording()
    for r in rec.robots:
        tr = r.trajectory
        yaw = _headings(tr["vx"], tr["vy"])
        rate = np.gradient(np.unwrap(yaw), tr["t"]) if tr["t"].size > 1 else np.zeros(1)
        for i in range(tr["t"].size):
            ns = _ns(float(tr["t"][i]))
            x, y = float(tr["x"][i]), float(tr["y"][i])
            hdr = w.header(ns, "world")
            p = w.pose(x, y, float(yaw[i]))
            tf = t["geometry_msgs/msg/TransformStamped"](
                header=hdr,
                child_frame_id=r.name,
                transform=t["geometry_msgs/msg/Transform"](
                    translation=t["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.0),
                    rotation=p.orientation,
                ),
            )
            out.add("/tf", TF_MESSAGE, ns, t[TF_MESSAGE](transforms=[tf]))
            out.add(
                f"/{r.name}/pose",
                "geometry_msgs/msg/PoseStamped",
                ns,
                t["geometry_msgs/msg/PoseStamped"](header=hdr, pose=p),
            )
            speed = math.hypot(float(tr["vx"][i]), float(tr["vy"][i]))
            out.add(f"/{r.name}/cmd_vel", TWIST, ns, w.twist(speed, 0.0, float(rate[i])))
            key = "d_min" if "d_min" in tr else "d_min_robot"
            out.add(f"/{r.name}/distance", FLOAT64, ns, w.float64(float(tr[key][i])))
        iv = r.intervals
        for j in range(iv["k"].size):
            ns = _ns(float(iv["t"][j]))
            out.add(f"/{r.name}/lambda", FLOAT64, ns, w.float64(float(iv["lambda"][j])))
            if math.isfinite(float(iv["loss"][j])):
                out.add(f"/{r.name}/loss", FLOAT64, ns, w.float64(float(iv["loss"][j])))
    _map(out, rec)
    if rec.has_scene:
        _scene(out, rec)
    return out


def _map(out: object, rec: RunRecord) -> None:
    from ..ros2 import writer as w
    from ..ros2.types import MARKER_ARRAY

    assert isinstance(out, w.Recording)
    hdr = w.header(0, "world")
    markers = []
    for m, r in enumerate(rec.robots):
        tr = r.trajectory
        path = list(zip(tr["x"].tolist(), tr["y"].tolist(), strict=True))
        markers.append(
            w.marker(
                hdr,
                f"{r.name}/path",
                0,
                w.LINE_STRIP,
                scale=(0.04, 0, 0),
                rgba=(0.2, 0.2, 0.2, 0.6),
                points=path,
            )
        )
        x0, y0 = (float(v) for v in rec.starts[m])
        markers.append(
            w.marker(
                hdr,
                f"{r.name}/start",
                0,
                w.SPHERE,
                at=w.pose(x0, y0),
                scale=(0.3, 0.3, 0.3),
                rgba=MAP_RGBA,
            )
        )
        goals = rec.goals[m] if m < len(rec.goals) else np.zeros((0, 2))
        for g, (gx, gy) in enumerate(goals.tolist()):
            d = 2.0 * rec.goal_radius
            markers.append(
                w.marker(
                    hdr,
                    f"{r.name}/goals",
                    g,
                    w.CYLINDER,
                    at=w.pose(gx, gy),
                    scale=(d, d, 0.02),
                    rgba=MAP_RGBA,
                )
            )
    out.add("/scene/map", MARKER_ARRAY, 0, w.marker_array(markers))


def _scene(out: object, rec: RunRecord) -> None:
    from ..ros2 import writer as w
    from ..ros2.types import MARKER_ARRAY

    assert isinstance(out, w.Recording)
    assert rec.frame_t is not None and rec.robots_xy is not None and rec.peds is not None
    d_robot, d_ped = 2.0 * rec.robot_radius, 2.0 * rec.agent_radius
    for f, tf in enumerate(rec.frame_t.tolist()):
        ns = _ns(tf)
        hdr = w.header(ns, "world")
        robots = [
            w.marker(
                hdr,
                "robots",
                m,
                w.CYLINDER,
                at=w.pose(float(xy[0]), float(xy[1]), z=ROBOT_HEIGHT / 2),
                scale=(d_robot, d_robot, ROBOT_HEIGHT),
                rgba=ROBOT_RGBA,
            )
            for m, xy in enumerate(rec.robots_xy[f])
            if np.isfinite(xy).all()
        ]
        out.add("/scene/robots", MARKER_ARRAY, ns, w.marker_array(robots))
        p = rec.peds[f]
        present = np.flatnonzero(np.isfinite(p[:, 0]))
        ids = rec.ped_ids if rec.ped_ids is not None else np.arange(p.shape[0])
        peds = [w.marker(hdr, "pedestrians", 0, w.CYLINDER, action=w.DELETEALL)]
        peds += [
            w.marker(
                hdr,
                "pedestrians",
                int(ids[c]),
                w.CYLINDER,
                at=w.pose(float(p[c, 0]), float(p[c, 1]), z=PED_HEIGHT / 2),
                scale=(d_ped, d_ped, PED_HEIGHT),
                rgba=PED_RGBA,
            )
            for c in present.tolist()
        ]
        out.add("/scene/pedestrians", MARKER_ARRAY, ns, w.marker_array(peds))
    for t0, cols, pred in rec.predictions:
        ns = _ns(t0)
        hdr = w.header(ns, "world")
        ids = rec.ped_ids if rec.ped_ids is not None else np.arange(rec.peds.shape[1])
        lines = [w.marker(hdr, "predictions", 0, w.LINE_STRIP, action=w.DELETEALL)]
        for c, path in zip(cols.tolist(), pred, strict=True):
            ok = np.isfinite(path[:, 0])
            if ok.sum() >= 2:
                lines.append(
                    w.marker(
                        hdr,
                        "predictions",
                        int(ids[c]),
                        w.LINE_STRIP,
                        scale=(0.06, 0, 0),
                        rgba=PRED_RGBA,
                        points=[(float(a), float(b)) for a, b in path[ok]],
                    )
                )
        out.add("/scene/predictions", MARKER_ARRAY, ns, w.marker_array(lines))


def write_ros2_mcap(run: str | Path | RunRecord, out: str | Path) -> Path:
    """Write a run as one MCAP file of ROS 2 messages (the module docstring's topics).

    Parameters
    ----------
    run : path or RunRecord
        A run directory or a record read by :func:`read_run`.
    out : path
        The ``.mcap`` file to write (its folder is created), through
        :func:`~conformal_control.io.export.destination.safe_output`: never a file of the run
        directory but an earlier ``.mcap``, never a link or a device.

    Returns
    -------
    Path
        ``out``.
    """
    from ..ros2.writer import Recording

    rec = run if isinstance(run, RunRecord) else read_run(run)
    recording = ros2_recording(rec)
    assert isinstance(recording, Recording)
    out = Path(out)
    meta = {
        "version": __version__,
        "kind": rec.kind,
        "scene": rec.scene,
        "epsilon": repr(rec.epsilon),
        "lambda_unit": rec.lambda_unit,
        "robots": " ".join(r.name for r in rec.robots),
        "scene_topics": "yes" if rec.has_scene else "no (no animation.npz)",
    }
    with safe_output(out, inputs=(rec.path,), suffix=".mcap") as fh:
        recording.write_mcap(
            fh,
            library=f"conformal-control {__version__}",
            metadata={"conformal_control": meta},
            attachments={"config.json": rec.config_bytes},
        )
    return out


def write_ros2_bag(run: str | Path | RunRecord, out: str | Path, *, storage: str = "mcap") -> Path:
    """Write a run as a ROS 2 bag folder (``metadata.yaml`` and one storage file), as
    ``ros2 bag record`` writes it; the folder must not exist.

    Parameters
    ----------
    run : path or RunRecord
        A run directory or a record read by :func:`read_run`.
    out : path
        The bag folder to create (written under a temporary name beside it, then renamed).
    storage : {"mcap", "sqlite3"}
        The storage plugin.

    Returns
    -------
    Path
        ``out``.
    """
    import shutil

    from ...core.exceptions import OutputNotWritableError
    from ..ros2.writer import Recording

    rec = run if isinstance(run, RunRecord) else read_run(run)
    out = Path(out)
    if out.exists() or out.is_symlink():
        raise OutputNotWritableError(
            f"{out} exists already: a bag is written into a new folder (give another --out)"
        )
    check_destination(out, inputs=(rec.path,))
    recording = ros2_recording(rec)
    assert isinstance(recording, Recording)
    out.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(dir=out.parent, prefix=f".{out.name}.", suffix=".partial"))
    try:
        bag = recording.write_bag(work / out.name, storage=storage)
        bag.rename(out)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return out
