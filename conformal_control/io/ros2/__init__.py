"""ROS 2 without ROS: read a robot's bags, run shadow mode, write ROS 2-typed files.

Needs the ``ros`` extra (``pip install 'conformal-control[ros]'``: ``rosbags``, pure
Python); the modules import it on first use.

* :func:`~conformal_control.io.ros2.bag.read_bag` -- the people and the odometry of a ROS 2
  bag (folder, ``.mcap`` or ``.db3``), in one frame;
* :func:`~conformal_control.io.ros2.shadow.shadow` -- ``conformal-control shadow``: what the
  conformal controller would have commanded on that recording;
* :class:`~conformal_control.io.ros2.writer.Recording` -- ROS 2 messages written as a bag
  folder or one MCAP file (the shadow outputs, ``export --schema ros2``);
* :func:`~conformal_control.io.ros2.types.typestore` -- the message types, ``people_msgs``
  registered from its ``.msg`` text;
* :func:`~conformal_control.io.ros2.example.scene_bag` -- a robot's bag made from a built-in
  scene (the documentation's example).
"""

from __future__ import annotations

from .bag import OdometryTrack, PeopleTrack, RecordedBag, read_bag
from .example import scene_bag
from .shadow import ShadowResult, shadow

__all__ = [
    "OdometryTrack",
    "PeopleTrack",
    "RecordedBag",
    "ShadowResult",
    "read_bag",
    "scene_bag",
    "shadow",
]
