"""Write ROS 2 messages: as a bag folder (``ros2 bag record``'s layout) or one MCAP file.

A :class:`Recording` collects messages (topic, type, time, message object of the
:func:`~conformal_control.io.ros2.types.typestore`) and writes them in time order:

* :meth:`Recording.write_bag`: a rosbag2 folder -- ``metadata.yaml`` and one storage file,
  MCAP (``ros2 bag record``'s default since Iron) or sqlite3 -- with ``rosbags``'
  writer, readable by ``ros2 bag play`` / ``ros2 bag info``;
* :meth:`Recording.write_mcap`: one MCAP file (profile ``ros2``, ``ros2msg`` schemas,
  ``cdr`` messages, as in a bag's storage file) into an open binary file, with the
  ``mcap`` writer; metadata records and attachments may be added (a bag folder has no
  place for them).

Both serialise with the same typestore (CDR, the message definitions generated from it),
so the two forms hold the same bytes. The message builders (:func:`header`,
:func:`twist`, :func:`float64`, :func:`marker`, ...) keep the call sites short.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from .types import msgdef, typestore

__all__ = [
    "STORAGES",
    "Recording",
    "float64",
    "header",
    "marker",
    "marker_array",
    "point",
    "pose",
    "twist",
]

#: Storage name -> file suffix of a bag folder's storage file.
STORAGES = {"mcap": ".mcap", "sqlite3": ".db3"}

#: visualization_msgs/Marker types and actions used here.
SPHERE, CYLINDER, LINE_STRIP, TEXT = 2, 3, 4, 9
ADD, DELETEALL = 0, 3


def _t(name: str) -> Any:
    return typestore().types[name]


def point(x: float, y: float, z: float = 0.0) -> Any:
    """``geometry_msgs/msg/Point``.

    Parameters
    ----------
    x, y, z : float
        Coordinates (m).
    """
    return _t("geometry_msgs/msg/Point")(x=float(x), y=float(y), z=float(z))


def header(ns: int, frame: str) -> Any:
    """``std_msgs/msg/Header`` stamped ``ns`` nanoseconds, in ``frame``.

    Parameters
    ----------
    ns : int
        The stamp (ns).
    frame : str
        The frame id.
    """
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    stamp = _t("builtin_interfaces/msg/Time")(sec=sec, nanosec=nanosec)
    return _t("std_msgs/msg/Header")(stamp=stamp, frame_id=frame)


def pose(x: float, y: float, yaw: float = 0.0, z: float = 0.0) -> Any:
    """``geometry_msgs/msg/Pose`` at (x, y, z), heading ``yaw`` (rad) about z.

    Parameters
    ----------
    x, y : float
        Position (m).
    yaw : float
        Heading (rad).
    z : float
        Height (m).
    """
    q = _t("geometry_msgs/msg/Quaternion")(
        x=0.0, y=0.0, z=math.sin(yaw / 2.0), w=math.cos(yaw / 2.0)
    )
    return _t("geometry_msgs/msg/Pose")(position=point(x, y, z), orientation=q)


def twist(vx: float, vy: float, wz: float = 0.0) -> Any:
    """``geometry_msgs/msg/Twist`` with linear (vx, vy, 0) (m/s) and angular (0, 0, wz)
    (rad/s).

    Parameters
    ----------
    vx, vy : float
        Linear velocity (m/s).
    wz : float
        Yaw rate (rad/s).
    """
    v3 = _t("geometry_msgs/msg/Vector3")
    return _t("geometry_msgs/msg/Twist")(
        linear=v3(x=float(vx), y=float(vy), z=0.0), angular=v3(x=0.0, y=0.0, z=float(wz))
    )


def float64(value: float) -> Any:
    """``std_msgs/msg/Float64``.

    Parameters
    ----------
    value : float
        The number (NaN allowed: CDR carries IEEE doubles).
    """
    return _t("std_msgs/msg/Float64")(data=float(value))


def marker(
    hdr: Any,
    ns: str,
    mid: int,
    kind: int,
    *,
    at: Any = None,
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0),
    rgba: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0),
    points: Sequence[tuple[float, float]] = (),
    text: str = "",
    action: int = ADD,
) -> Any:
    """``visualization_msgs/msg/Marker``.

    Parameters
    ----------
    hdr : Header
        Its header (stamp and frame).
    ns : str
        Namespace.
    mid : int
        Id within the namespace.
    kind : int
        Marker type (2 sphere, 3 cylinder, 4 line strip, 9 text).
    at : Pose, optional
        Its pose (default: the origin).
    scale : tuple of float
        Size (m): diameters and height for shapes, (width, 0, 0) for lines.
    rgba : tuple of float
        Colour, each in [0, 1].
    points : sequence of (x, y)
        The line strip's points (m).
    text : str
        A text marker's text.
    action : int
        0 add, 3 delete all.
    """
    t = typestore().types
    dur = t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0)
    return t["visualization_msgs/msg/Marker"](
        header=hdr,
        ns=ns,
        id=int(mid),
        type=int(kind),
        action=int(action),
        pose=at if at is not None else pose(0.0, 0.0),
        scale=t["geometry_msgs/msg/Vector3"](x=scale[0], y=scale[1], z=scale[2]),
        color=t["std_msgs/msg/ColorRGBA"](r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]),
        lifetime=dur,
        frame_locked=False,
        points=[point(x, y) for x, y in points],
        colors=[],
        texture_resource="",
        texture=t["sensor_msgs/msg/CompressedImage"](
            header=header(0, ""), format="", data=_empty_bytes()
        ),
        uv_coordinates=[],
        text=text,
        mesh_resource="",
        mesh_file=t["visualization_msgs/msg/MeshFile"](filename="", data=_empty_bytes()),
        mesh_use_embedded_materials=False,
    )


def _empty_bytes() -> Any:
    import numpy as np

    return np.zeros(0, dtype=np.uint8)


def marker_array(markers: Sequence[Any]) -> Any:
    """``visualization_msgs/msg/MarkerArray``.

    Parameters
    ----------
    markers : sequence of Marker
        Its markers.
    """
    return _t("visualization_msgs/msg/MarkerArray")(markers=list(markers))


@dataclass
class Recording:
    """ROS 2 messages to write, kept in the order added per topic and written sorted by
    time (stable: a topic's order is kept)."""

    #: (time ns, topic, message type, message)
    messages: list[tuple[int, str, str, Any]] = field(default_factory=list)
    #: topic -> message type (one type per topic)
    topics: dict[str, str] = field(default_factory=dict)

    def add(self, topic: str, msgtype: str, ns: int, message: Any) -> None:
        """Add one message.

        Parameters
        ----------
        topic : str
            The topic.
        msgtype : str
            Its type, e.g. ``geometry_msgs/msg/Twist``.
        ns : int
            Its time (ns): the bag's receive time (the header, if any, is the caller's).
        message : object
            A message object of the typestore.
        """
        have = self.topics.setdefault(topic, msgtype)
        if have != msgtype:
            raise ValueError(f"topic {topic} holds {have}, not {msgtype}")
        self.messages.append((int(ns), topic, msgtype, message))

    def _sorted(self) -> list[tuple[int, str, str, Any]]:
        return sorted(self.messages, key=lambda m: m[0])

    def write_bag(self, path: str | Path, storage: str = "mcap") -> Path:
        """Write a rosbag2 folder (it must not exist; rosbags creates it).

        Parameters
        ----------
        path : path
            The bag folder to create.
        storage : {"mcap", "sqlite3"}
            The storage plugin.

        Returns
        -------
        Path
            ``path``.
        """
        from rosbags.rosbag2 import StoragePlugin, Writer

        if storage not in STORAGES:
            raise ValueError(f"unknown storage {storage!r} (choose from {', '.join(STORAGES)})")
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        store = typestore()
        with Writer(Path(path), version=Writer.VERSION_LATEST, storage_plugin=plugin) as w:
            conns = {
                topic: w.add_connection(topic, msgtype, typestore=store)
                for topic, msgtype in self.topics.items()
            }
            for ns, topic, msgtype, message in self._sorted():
                w.write(conns[topic], ns, store.serialize_cdr(message, msgtype))
        return Path(path)

    def write_mcap(
        self,
        fh: IO[bytes],
        *,
        library: str,
        metadata: dict[str, dict[str, str]] | None = None,
        attachments: dict[str, bytes] | None = None,
    ) -> None:
        """Write one MCAP file into the open binary file ``fh``.

        Parameters
        ----------
        fh : binary file
            Where to write.
        library : str
            The writer's name recorded in the file's header.
        metadata : dict, optional
            Metadata records: name -> {key: value}.
        attachments : dict, optional
            Attached files: name -> bytes (JSON files get media type application/json).
        """
        from mcap.writer import CompressionType, Writer

        store = typestore()
        writer = Writer(fh, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library=library)
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        for topic, msgtype in self.topics.items():
            if msgtype not in schemas:
                schemas[msgtype] = writer.register_schema(
                    name=msgtype, encoding="ros2msg", data=msgdef(msgtype).encode()
                )
            channels[topic] = writer.register_channel(
                topic=topic, message_encoding="cdr", schema_id=schemas[msgtype]
            )
        sequence = dict.fromkeys(self.topics, 0)
        for ns, topic, msgtype, message in self._sorted():
            writer.add_message(
                channel_id=channels[topic],
                log_time=ns,
                publish_time=ns,
                sequence=sequence[topic],
                data=bytes(store.serialize_cdr(message, msgtype)),
            )
            sequence[topic] += 1
        for name, record in (metadata or {}).items():
            writer.add_metadata(name, record)
        for name, data in (attachments or {}).items():
            media = "application/json" if name.endswith(".json") else "application/octet-stream"
            writer.add_attachment(create_time=0, log_time=0, name=name, media_type=media, data=data)
        writer.finish()  # type: ignore[no-untyped-call]  # mcap's Writer.finish is unannotated
