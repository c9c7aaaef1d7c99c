"""Write the example robot bag of the docs page "On your robot's logs".

A robot driven straight through the built-in ``crossing`` scene's crowd, recorded as a
ROS 2 bag (no data from elsewhere): ``/people`` (people_msgs/msg/People, frame ``map``),
``/tracked_people`` (visualization_msgs/msg/MarkerArray), ``/odom`` (nav_msgs/msg/Odometry,
50 Hz, ``odom`` -> ``base_link``) and ``/tf_static`` (``map`` -> ``odom``). The goal, in
``odom``, is (26, 0).

    python examples/robot_bag.py crossing_bag                    # MCAP storage
    python examples/robot_bag.py crossing_db3 --storage sqlite3  # sqlite3 storage
"""

from __future__ import annotations

import argparse

from conformal_control.io.ros2 import scene_bag


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    parser.add_argument("out", help="the bag folder to create")
    parser.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    parser.add_argument("--seconds", type=float, default=30.0, help="length (s)")
    args = parser.parse_args(argv)
    path = scene_bag(args.out, "crossing", storage=args.storage, seconds=args.seconds)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
