"""Files in and out: exporting runs (MCAP, Rerun, ROS 2), figures, and ROS 2 bags
(reading a robot's recording, shadow mode over it)."""
