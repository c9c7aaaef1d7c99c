"""Foxglove's message schemas (JSON Schema) and the messages of an exported run.

Foxglove recognises its schemas by name (``foxglove.SceneUpdate``, ``foxglove.FrameTransform``,
``foxglove.PoseInFrame``, ...) on channels with message encoding ``json`` and schema encoding
``jsonschema``. The schemas below are Foxglove's published definitions of these messages
(the ``foxglove/schemas`` repository, MIT), built from their parts (time, Vector3,
Quaternion, Pose, Color, the primitives) instead of pasted: the same titles, fields and
types, without the field descriptions (``tests/io/export/test_foxglove.py`` checks that they
equal the published definitions, descriptions left out, through a fingerprint of their
canonical JSON).

The run's own quantities (lambda, loss, distance, speed, ...) go on channels with schemas
of our own (``conformal_control.RobotState``, ``conformal_control.ConformalInterval``):
flat objects of numbers, which Foxglove's Plot panel reads by path (``/robot/state.d_min``).
"""

from __future__ import annotations

import math
from typing import Any

__all__ = [
    "FRAME_TRANSFORM",
    "INTERVAL",
    "POSE_IN_FRAME",
    "ROBOT_STATE",
    "SCENE_UPDATE",
    "color",
    "cylinder",
    "entity",
    "frame_transform",
    "line",
    "pose",
    "pose_in_frame",
    "scene_update",
    "sphere",
    "text",
    "time",
]

Json = dict[str, Any]


# ------------------------------------------------------------------------------ schemas
def _obj(title: str, properties: dict[str, Any]) -> Json:
    return {"title": title, "type": "object", "properties": properties}


def _num() -> Json:
    return {"type": "number"}


def _array(items: Json) -> Json:
    return {"type": "array", "items": items}


def _time(title: str = "time") -> Json:
    nsec = {"type": "integer", "minimum": 0, "maximum": 999_999_999}
    sec: Json = {"type": "integer", "minimum": 0} if title == "time" else {"type": "integer"}
    return {"type": "object", "title": title, "properties": {"sec": sec, "nsec": nsec}}


def _vector3() -> Json:
    return _obj("foxglove.Vector3", {"x": _num(), "y": _num(), "z": _num()})


def _point3() -> Json:
    return _obj("foxglove.Point3", {"x": _num(), "y": _num(), "z": _num()})


def _quaternion() -> Json:
    return _obj("foxglove.Quaternion", {"x": _num(), "y": _num(), "z": _num(), "w": _num()})


def _pose() -> Json:
    return _obj("foxglove.Pose", {"position": _vector3(), "orientation": _quaternion()})


def _color() -> Json:
    return _obj("foxglove.Color", {"r": _num(), "g": _num(), "b": _num(), "a": _num()})


def _enum(title: str, values: list[str]) -> Json:
    return {"title": title, "oneOf": [{"title": v, "const": i} for i, v in enumerate(values)]}


def _scene_entity() -> Json:
    arrow = _obj(
        "foxglove.ArrowPrimitive",
        {
            "pose": _pose(),
            "shaft_length": _num(),
            "shaft_diameter": _num(),
            "head_length": _num(),
            "head_diameter": _num(),
            "color": _color(),
        },
    )
    cube = _obj("foxglove.CubePrimitive", {"pose": _pose(), "size": _vector3(), "color": _color()})
    triangles = _obj(
        "foxglove.TriangleListPrimitive",
        {
            "pose": _pose(),
            "points": _array(_point3()),
            "color": _color(),
            "colors": _array(_color()),
            "indices": _array({"type": "integer", "minimum": 0}),
        },
    )
    model = _obj(
        "foxglove.ModelPrimitive",
        {
            "pose": _pose(),
            "scale": _vector3(),
            "color": _color(),
            "override_color": {"type": "boolean"},
            "url": {"type": "string"},
            "media_type": {"type": "string"},
            "data": {"type": "string", "contentEncoding": "base64"},
        },
    )
    sphere = _obj(
        "foxglove.SpherePrimitive", {"pose": _pose(), "size": _vector3(), "color": _color()}
    )
    cylinder = _obj(
        "foxglove.CylinderPrimitive",
        {
            "pose": _pose(),
            "size": _vector3(),
            "bottom_scale": _num(),
            "top_scale": _num(),
            "color": _color(),
        },
    )
    line = _obj(
        "foxglove.LinePrimitive",
        {
            "type": _enum("foxglove.LineType", ["LINE_STRIP", "LINE_LOOP", "LINE_LIST"]),
            "pose": _pose(),
            "thickness": _num(),
            "scale_invariant": {"type": "boolean"},
            "points": _array(_point3()),
            "color": _color(),
            "colors": _array(_color()),
            "indices": _array({"type": "integer", "minimum": 0}),
        },
    )
    text = _obj(
        "foxglove.TextPrimitive",
        {
            "pose": _pose(),
            "billboard": {"type": "boolean"},
            "font_size": _num(),
            "scale_invariant": {"type": "boolean"},
            "color": _color(),
            "text": {"type": "string"},
        },
    )
    key_value = _obj(
        "foxglove.KeyValuePair", {"key": {"type": "string"}, "value": {"type": "string"}}
    )
    return _obj(
        "foxglove.SceneEntity",
        {
            "timestamp": _time(),
            "frame_id": {"type": "string"},
            "id": {"type": "string"},
            "lifetime": _time("duration"),
            "frame_locked": {"type": "boolean"},
            "metadata": _array(key_value),
            "arrows": _array(arrow),
            "cubes": _array(cube),
            "spheres": _array(sphere),
            "cylinders": _array(cylinder),
            "lines": _array(line),
            "triangles": _array(triangles),
            "texts": _array(text),
            "models": _array(model),
        },
    )


def _scene_update() -> Json:
    deletion = _obj(
        "foxglove.SceneEntityDeletion",
        {
            "timestamp": _time(),
            "type": _enum("foxglove.SceneEntityDeletionType", ["MATCHING_ID", "ALL"]),
            "id": {"type": "string"},
        },
    )
    return _obj(
        "foxglove.SceneUpdate",
        {"deletions": _array(deletion), "entities": _array(_scene_entity())},
    )


def _numbers(title: str, fields: dict[str, str]) -> Json:
    """A flat schema of our own: field -> ``number`` (null allowed), ``integer`` or ``string``."""
    props: dict[str, Any] = {}
    for name, kind in fields.items():
        props[name] = {"type": ["number", "null"]} if kind == "number" else {"type": kind}
    return _obj(title, props)


#: schema name -> JSON schema
SCENE_UPDATE: Json = _scene_update()
FRAME_TRANSFORM: Json = _obj(
    "foxglove.FrameTransform",
    {
        "timestamp": _time(),
        "parent_frame_id": {"type": "string"},
        "child_frame_id": {"type": "string"},
        "translation": _vector3(),
        "rotation": _quaternion(),
    },
)
POSE_IN_FRAME: Json = _obj(
    "foxglove.PoseInFrame",
    {"timestamp": _time(), "frame_id": {"type": "string"}, "pose": _pose()},
)
ROBOT_STATE: Json = _numbers(
    "conformal_control.RobotState",
    {
        "frame": "integer",
        "t": "number",
        "x": "number",
        "y": "number",
        "vx": "number",
        "vy": "number",
        "speed": "number",
        "d_min": "number",
        "d_min_robot": "number",
        "status": "integer",
        "h_true_min": "number",
    },
)
INTERVAL: Json = _numbers(
    "conformal_control.ConformalInterval",
    {
        "k": "integer",
        "t": "number",
        "lambda": "number",
        "loss": "number",
        "loss_applied": "number",
        "max_gap": "number",
        "n_sensed": "integer",
        "n_steps": "integer",
        "epsilon": "number",
    },
)


# ------------------------------------------------------------------------------ messages
def time(ns: int) -> Json:
    """A Foxglove time from nanoseconds."""
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def color(rgba: tuple[float, float, float, float]) -> Json:
    r, g, b, a = rgba
    return {"r": r, "g": g, "b": b, "a": a}


def yaw_quaternion(yaw: float) -> Json:
    """The rotation by ``yaw`` (rad) about z."""
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2.0), "w": math.cos(yaw / 2.0)}


def pose(x: float, y: float, z: float = 0.0, yaw: float = 0.0) -> Json:
    """A Foxglove ``Pose``: a position and a rotation about the vertical axis.

    Parameters
    ----------
    x, y, z : float
        Position (m) in the message's frame.
    yaw : float
        Rotation about z (rad, counter-clockwise from the x axis).
    """
    return {"position": {"x": x, "y": y, "z": z}, "orientation": yaw_quaternion(yaw)}


def cylinder(
    x: float, y: float, diameter: float, height: float, rgba: tuple[float, float, float, float]
) -> Json:
    """An upright cylinder standing on the ground at (x, y).

    Parameters
    ----------
    x, y : float
        Centre of its base (m).
    diameter : float
        Its diameter (m).
    height : float
        Its height (m).
    rgba : tuple of 4 floats
        Red, green, blue and opacity, each in [0, 1].
    """
    return {
        "pose": pose(x, y, height / 2.0),
        "size": {"x": diameter, "y": diameter, "z": height},
        "bottom_scale": 1.0,
        "top_scale": 1.0,
        "color": color(rgba),
    }


def sphere(
    x: float, y: float, diameter: float, rgba: tuple[float, float, float, float], z: float = 0.0
) -> Json:
    """A sphere centred at (x, y, z).

    Parameters
    ----------
    x, y : float
        Its centre on the ground plane (m).
    diameter : float
        Its diameter (m).
    rgba : tuple of 4 floats
        Red, green, blue and opacity, each in [0, 1].
    z : float
        Height of its centre (m).
    """
    return {
        "pose": pose(x, y, z),
        "size": {"x": diameter, "y": diameter, "z": diameter},
        "color": color(rgba),
    }


def line(
    points: list[tuple[float, float]],
    rgba: tuple[float, float, float, float],
    *,
    thickness: float = 0.05,
    loop: bool = False,
    z: float = 0.02,
) -> Json:
    """A line strip (or a closed loop) on the ground.

    Parameters
    ----------
    points : list of (x, y)
        Its vertices in order (m).
    rgba : tuple of 4 floats
        Red, green, blue and opacity, each in [0, 1].
    thickness : float
        Line width (m).
    loop : bool
        Close the strip (last vertex joined to the first).
    z : float
        Height of the line above the ground (m; a little above it, to be drawn over it).
    """
    return {
        "type": 1 if loop else 0,
        "pose": pose(0.0, 0.0),
        "thickness": thickness,
        "scale_invariant": False,
        "points": [{"x": x, "y": y, "z": z} for x, y in points],
        "color": color(rgba),
        "colors": [],
        "indices": [],
    }


def text(x: float, y: float, z: float, label: str, rgba: tuple[float, float, float, float]) -> Json:
    """A label at (x, y, z), always facing the camera, 14 px high on screen.

    Parameters
    ----------
    x, y, z : float
        Its anchor (m).
    label : str
        The text shown.
    rgba : tuple of 4 floats
        Red, green, blue and opacity, each in [0, 1].
    """
    return {
        "pose": pose(x, y, z),
        "billboard": True,
        "font_size": 14.0,
        "scale_invariant": True,
        "color": color(rgba),
        "text": label,
    }


def entity(
    ns: int,
    frame_id: str,
    entity_id: str,
    *,
    frame_locked: bool = False,
    metadata: dict[str, str] | None = None,
    **primitives: list[Json],
) -> Json:
    """A scene entity (every primitive array present, empty unless given).

    Parameters
    ----------
    ns : int
        Its timestamp (ns).
    frame_id : str
        The frame its primitives are given in.
    entity_id : str
        Its id: an entity with the same id replaces the previous one.
    frame_locked : bool
        Whether it moves with its frame after the timestamp (Foxglove's
        ``frame_locked``).
    metadata : dict of str to str, optional
        Key-value pairs shown with the entity (None: none).
    **primitives : list of dict
        Primitive arrays by kind: ``arrows``, ``cubes``, ``spheres``, ``cylinders``,
        ``lines``, ``triangles``, ``texts``, ``models`` (another kind is a ``TypeError``).
    """
    out: Json = {
        "timestamp": time(ns),
        "frame_id": frame_id,
        "id": entity_id,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": frame_locked,
        "metadata": [{"key": k, "value": v} for k, v in (metadata or {}).items()],
    }
    for name in ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts"):
        out[name] = primitives.pop(name, [])
    out["models"] = primitives.pop("models", [])
    if primitives:
        raise TypeError(f"unknown primitive kind(s): {', '.join(sorted(primitives))}")
    return out


def scene_update(entities: list[Json], deletions: list[Json] | None = None) -> Json:
    return {"deletions": deletions or [], "entities": entities}


def frame_transform(ns: int, parent: str, child: str, x: float, y: float, yaw: float) -> Json:
    """A Foxglove ``FrameTransform``: frame ``child`` placed in frame ``parent`` on the
    ground plane.

    Parameters
    ----------
    ns : int
        Its timestamp (ns).
    parent, child : str
        The frame ids.
    x, y : float
        The child's origin in the parent frame (m).
    yaw : float
        The child's rotation about z (rad).
    """
    return {
        "timestamp": time(ns),
        "parent_frame_id": parent,
        "child_frame_id": child,
        "translation": {"x": x, "y": y, "z": 0.0},
        "rotation": yaw_quaternion(yaw),
    }


def pose_in_frame(ns: int, frame_id: str, x: float, y: float, yaw: float) -> Json:
    """A Foxglove ``PoseInFrame`` on the ground plane.

    Parameters
    ----------
    ns : int
        Its timestamp (ns).
    frame_id : str
        The frame the pose is given in.
    x, y : float
        Position (m).
    yaw : float
        Heading (rad, counter-clockwise from the x axis).
    """
    return {"timestamp": time(ns), "frame_id": frame_id, "pose": pose(x, y, 0.0, yaw)}
