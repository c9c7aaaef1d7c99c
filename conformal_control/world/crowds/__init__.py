"""Pedestrians who react to the robot: crowd models seeded from the recorded scene.

* :class:`~conformal_control.world.crowds.social_force.SocialForceModel` - Helbing & Molnár
  (1995) with the interaction of Moussaïd et al. (2009), in numpy;
* :class:`~conformal_control.world.crowds.orca.ORCAModel` - optimal reciprocal collision
  avoidance (van den Berg et al. 2011), its linear programs solved exactly in numpy;
* :class:`~conformal_control.world.crowds.crowd.Crowd` - seeds a model from the recording
  (positions, velocities, waypoints) and runs it around the robot, in full or mixed mode;
* the episode's environment with such a crowd is
  :class:`~conformal_control.world.reactive.ReactiveEnvironment` (built by
  :func:`~conformal_control.world.reactive.make_environment`, ``crowd="replay" |
  "social_force" | "orca" | "mixed"``).
"""

from .base import CrowdModel
from .crowd import Crowd, build_model, model_names
from .orca import ORCAModel
from .social_force import SocialForceModel

__all__ = [
    "Crowd",
    "CrowdModel",
    "ORCAModel",
    "SocialForceModel",
    "build_model",
    "model_names",
]
