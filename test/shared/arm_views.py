"""The 3DT grid the arm tests plan in and a view beside the camera's reference pose, shared by
test/unit and test/studies."""

from __future__ import annotations

import numpy as np

from nbv_prob_cnn.basics.camera import DATASETS, matrix_from_quaternion
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.planners import ViewChoice

GEOMETRY_3DT = GridGeometry((0.0, 0.0, 0.0), DATASETS["3dt"].resolution_m, DATASETS["3dt"].shape)


def near_view(robot, context) -> ViewChoice:
    """A view 5 cm beside the camera's reference pose, in the orientation closest to its own."""
    pose = robot.camera_pose(robot.reference_q)
    cell, inside = GEOMETRY_3DT.containing_cell(pose[:3, 3] + np.array([0.0, 0.05, 0.0]))
    assert inside
    angles = [np.trace(matrix_from_quaternion(q).T @ pose[:3, :3]) for q in context.orientations]
    return ViewChoice(cell, int(np.argmax(angles)), 0.5)
