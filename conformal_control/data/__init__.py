"""Data: loaders (SDD raw and TrajNet), scenes, the built-in scene, data-root handling."""

from .catalog import load_scene
from .paths import ENV_VAR, DataNotFoundError, ethucy_root, resolve_data_root, sdd_root
from .scene import Scene, scene_from_tracks
from .scenes import PAPER_SCENES, TABLE_I, TABLE_II, scene_names
from .sdd import SDD_FPS, load_scales, read_annotations, sdd_video
from .synthetic import crossing_scene
from .tracks import Tracks
from .trajnet import read_trajnet

__all__ = [
    "ENV_VAR",
    "PAPER_SCENES",
    "SDD_FPS",
    "TABLE_I",
    "TABLE_II",
    "DataNotFoundError",
    "Scene",
    "Tracks",
    "crossing_scene",
    "ethucy_root",
    "load_scales",
    "load_scene",
    "read_annotations",
    "read_trajnet",
    "resolve_data_root",
    "scene_from_tracks",
    "scene_names",
    "sdd_root",
    "sdd_video",
]
