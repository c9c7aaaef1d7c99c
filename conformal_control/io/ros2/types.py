"""The ROS 2 message types the toolkit reads and writes, without ROS installed.

:func:`typestore` is a ``rosbags`` typestore of the standard messages (ROS 2 Humble's
``std_msgs``, ``geometry_msgs``, ``nav_msgs``, ``visualization_msgs``, ``tf2_msgs``, ...)
with ``people_msgs`` added: its two messages are not in any ROS distribution's core set,
so they are registered here from their ``.msg`` text (the ROS 2 ``people`` package's
definitions, below) with ``rosbags.typesys.get_types_from_msg``. Reading a bag, the
definitions the bag itself carries take precedence (``rosbags``' ``AnyReader``); this
store serialises what we write and reads bags recorded without definitions.

Needs the ``ros`` extra (``rosbags``); importing this module without it raises an
``ImportError`` that says so.
"""

from __future__ import annotations

import functools
from typing import Any

__all__ = [
    "FLOAT64",
    "MARKER_ARRAY",
    "ODOMETRY",
    "PEOPLE",
    "PEOPLE_MSGS",
    "TF_MESSAGE",
    "TWIST",
    "msgdef",
    "require_rosbags",
    "typestore",
]

PEOPLE = "people_msgs/msg/People"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
ODOMETRY = "nav_msgs/msg/Odometry"
TWIST = "geometry_msgs/msg/Twist"
FLOAT64 = "std_msgs/msg/Float64"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"

#: ``people_msgs`` as the ROS 2 ``people`` package defines it: type name -> ``.msg`` text.
PEOPLE_MSGS = {
    "people_msgs/msg/Person": (
        "string name\n"
        "geometry_msgs/Point position\n"
        "geometry_msgs/Point velocity\n"
        "float64 reliability\n"
        "string[] tagnames\n"
        "string[] tags\n"
    ),
    PEOPLE: "std_msgs/Header header\npeople_msgs/Person[] people\n",
}


def require_rosbags() -> None:
    """Raise a one-line ``ImportError`` naming the extra when ``rosbags`` is missing."""
    try:
        import rosbags  # noqa: F401
    except ImportError as exc:
        raise ImportError(
            "reading and writing ROS 2 bags needs the ros extra: "
            "pip install 'conformal-control[ros]'"
        ) from exc


@functools.lru_cache(maxsize=1)
def typestore() -> Any:
    """The typestore of ROS 2 Humble's standard messages plus ``people_msgs`` (shared,
    built once; a ``rosbags.typesys.store.Typestore``)."""
    require_rosbags()
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types: dict[str, Any] = {}
    for name, text in PEOPLE_MSGS.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def msgdef(msgtype: str) -> str:
    """The ``ros2msg`` definition text of ``msgtype`` with its dependencies, as ROS 2 bags
    and MCAP files carry it in their schemas."""
    text: str = typestore().generate_msgdef(msgtype, ros_version=2)[0]
    return text
