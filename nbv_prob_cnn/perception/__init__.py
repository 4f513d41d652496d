"""Perception: simulated depth camera, TSDF integration to ternary grids, rosbag2 I/O (no ROS needed)."""

from nbv_prob_cnn.perception.bags import BagError, BagWriter, Frame, read_frames
from nbv_prob_cnn.perception.depth_camera import DepthCamera, DepthNoise, Intrinsics, room_mesh
from nbv_prob_cnn.perception.tsdf import TsdfIntegrator, depth_to_metres, load_grid, save_grid

__all__ = [
    "BagError",
    "BagWriter",
    "DepthCamera",
    "DepthNoise",
    "Frame",
    "Intrinsics",
    "TsdfIntegrator",
    "depth_to_metres",
    "load_grid",
    "read_frames",
    "room_mesh",
    "save_grid",
]
