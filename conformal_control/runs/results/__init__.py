"""What runs produce: metrics tables (one robot, a fleet), the episode result, the
animation record, the measuring code every engine shares, and run directories."""

from .episode import EpisodeResult, RobotResult
from .metrics import EpisodeMetrics
from .multi_metrics import FleetMetrics
from .rundir import write_run_dir

__all__ = ["EpisodeMetrics", "EpisodeResult", "FleetMetrics", "RobotResult", "write_run_dir"]
