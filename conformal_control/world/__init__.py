"""The world an episode runs in: recorded pedestrians replayed, pedestrians who react to
the robot, several robots in one crowd; the sensor that hands a decision family its
observations and reveals the truth at the next sampling time."""

from .reactive import ReactiveEnvironment, make_environment
from .replay import FrameLog, ReplayEnvironment

__all__ = ["FrameLog", "ReactiveEnvironment", "ReplayEnvironment", "make_environment"]
