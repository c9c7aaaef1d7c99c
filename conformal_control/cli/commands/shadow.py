"""``conformal-control shadow BAG``: what the conformal controller would have commanded on a
robot's ROS 2 bag (the work is :func:`conformal_control.io.ros2.shadow.shadow`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from . import check_writable, command, key_values


def _xy(text: str) -> tuple[float, float]:
    """argparse type: ``X,Y`` in metres."""
    import math

    parts = text.split(",")
    try:
        x, y = (float(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y in metres, got {text!r}") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise argparse.ArgumentTypeError(f"expected finite X,Y, got {text!r}")
    return x, y


@command(
    "shadow",
    "run the conformal controller over a robot's ROS 2 bag: the commands it would have sent",
)
def _shadow_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "bag",
        metavar="BAG",
        help="a ROS 2 bag: its folder (with metadata.yaml), or a .mcap or .db3 file",
    )
    p.add_argument(
        "--goal",
        type=_xy,
        required=True,
        metavar="X,Y",
        help="the robot's goal (m) in the odometry's frame",
    )
    p.add_argument(
        "--people-topic",
        default="/people",
        help="people_msgs/msg/People (ids from name) or visualization_msgs/msg/MarkerArray "
        "(ids from ns/id) (default /people)",
    )
    p.add_argument(
        "--odom-topic", default="/odom", help="nav_msgs/msg/Odometry topic (default /odom)"
    )
    p.add_argument(
        "--family",
        default="cbf",
        help="the conformal CBF controller (cbf, default) or any registered planning family "
        "(mpc, acp_mpc, ecp_mpc, fcp_mpc, soft_mpc or a plugin's; `conformal-control plugins` "
        "lists them)",
    )
    p.add_argument("--predictor", default="constant_velocity", help="registered predictor name")
    p.add_argument(
        "--param",
        action="append",
        metavar="KEY=VALUE",
        help="a controller setting, SI units (epsilon, eta, d_c, v_max, ...; tau, default "
        "0.4 s; dt, default from the people topic's rate; substeps, default 1; "
        "sensing_radius); repeatable",
    )
    p.add_argument(
        "--out",
        required=True,
        metavar="DIR",
        help="output folder: commands.csv, config.json, shadow_bag/ (ROS 2 bag), plot.png, "
        "guarantee.png",
    )
    p.add_argument("--no-plots", action="store_true", help="skip plot.png and guarantee.png")


@_shadow_args.handler
def _shadow(args: argparse.Namespace) -> int:
    from ...io.ros2.shadow import shadow

    out = check_writable(args.out)
    params = key_values(args.param, "--param")
    res = shadow(
        args.bag,
        args.goal,
        people_topic=args.people_topic,
        odom_topic=args.odom_topic,
        family=args.family,
        predictor=args.predictor,
        params=params,
    )
    res.save(out, plots=not args.no_plots)
    print(res.summary())
    print(f"results written to {Path(out)}")
    return 0
