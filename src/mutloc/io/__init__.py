"""File formats: rig files, observation files, JSON results."""

from __future__ import annotations

from ._files import output_folder, writable_path
from .observations import load_observations
from .pointcloud import read_ply, write_ply
from .results import dumps_json, write_json
from .kalibr import load_kalibr_camchain
from .rig import load_camera_file, load_rig, save_rig

__all__ = ["load_rig", "save_rig", "load_camera_file", "load_kalibr_camchain", "load_observations", "write_json", "dumps_json", "write_ply", "read_ply",
           "output_folder", "writable_path"]
