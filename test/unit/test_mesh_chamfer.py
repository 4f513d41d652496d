"""The Chamfer distance of a run's TSDF mesh, on a hand-worked scene, and in ``nbv explore``."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
import trimesh

from nbv_prob_cnn.basics.camera import quaternion_from_matrix
from nbv_prob_cnn.basics.datasets import dataset_spec
from nbv_prob_cnn.basics.sensor import Sensor
from nbv_prob_cnn.exploration.mesh_chamfer import MeshReconstruction, canonical_order, sensor_intrinsics
from nbv_prob_cnn.sensing.observe import camera_rays
from nbv_prob_cnn.worlds.world import World

VOXEL = 0.01
#: 12 × 12 cells, centred on x = y = 0.24 m
LOW, HIGH = 0.18, 0.30
TOP_Z, HIDDEN_Z = 0.30, 0.20  # the hidden square 10 cells straight below the top one


def square(z: float) -> trimesh.Trimesh:
    vertices = [[LOW, LOW, z], [HIGH, LOW, z], [HIGH, HIGH, z], [LOW, HIGH, z]]
    return trimesh.Trimesh(vertices, [[0, 1, 2], [0, 2, 3]], process=False)


class TwoSquares(World):
    """A 48³ grid of 1 cm cells whose meshes are two parallel squares, one above the other; its
    ground truth empty, or (``slab``) a slab between their heights over the whole grid, which
    closes off the space below it, as 3DT's table does."""

    def __init__(self, slab: bool = False) -> None:
        truth = np.zeros((48, 48, 48), np.uint8)
        if slab:
            truth[:, :, round(HIDDEN_Z / VOXEL) : round(TOP_Z / VOXEL)] = 1
        super().__init__("3dt", 0, 0, truth, VOXEL, np.zeros(3))

    def triangle_meshes(self) -> list[trimesh.Trimesh]:
        return [square(TOP_Z), square(HIDDEN_Z)]


@pytest.mark.parametrize("dataset", ["3dt", "3du"])
def test_the_depth_image_has_the_voxel_sensors_rays(dataset):
    sensor = dataset_spec(dataset).sensor
    intrinsics = sensor_intrinsics(sensor)
    pixels = intrinsics.pixel_rays().reshape(-1, 3)
    np.testing.assert_allclose(pixels / np.linalg.norm(pixels, axis=1, keepdims=True), camera_rays(sensor, 3),
                               atol=1e-12)  # fmt: skip


def test_chamfer_of_a_seen_square_above_a_hidden_one():
    """One view straight down sees the whole top square and nothing of the one 10 cm below it.
    Accuracy: the TSDF mesh lies on the top square (0). Completeness: the top square's points are
    on the mesh (0), the hidden square's, of the same area, 10 cm from it, so their mean is 5 cm
    and the Chamfer distance 2.5 cm."""
    world = TwoSquares()
    reconstruction = MeshReconstruction(world, Sensor(60.0, 46.0, 32))
    # 17 cm above the top square the image spans +-9.8 x +-7.2 cm there: the whole 12 x 12 cm
    look_down = np.diag([1.0, -1.0, -1.0])  # optical z along world -z, x along x
    reconstruction.add_view(np.array([0.24, 0.24, 0.47]), quaternion_from_matrix(look_down))
    result = reconstruction.chamfer()
    assert result.views == 1 and result.mesh_vertices > 100
    assert result.accuracy_m < 0.05 * VOXEL
    depth = TOP_Z - HIDDEN_Z
    assert result.completeness_m == pytest.approx(depth / 2, rel=0.03)
    assert result.distance_m == pytest.approx(depth / 4, rel=0.03)
    assert result.distance_m == (result.accuracy_m + result.completeness_m) / 2
    assert result.describe().startswith(f"Chamfer {1000 * result.distance_m:.2f} mm (accuracy")


def test_chamfer_counts_only_the_true_surface_facing_the_first_views_free_space():
    """The same view with the hidden square the underside of a slab over the whole grid: it faces
    the closed space below, not the camera's, so it is no part of the visible truth and the
    Chamfer distance is 0 (the top square seen whole)."""
    reconstruction = MeshReconstruction(TwoSquares(slab=True), Sensor(60.0, 46.0, 32))
    reconstruction.add_view(np.array([0.24, 0.24, 0.47]), quaternion_from_matrix(np.diag([1.0, -1.0, -1.0])))
    result = reconstruction.chamfer()
    assert result.accuracy_m < 0.05 * VOXEL and result.completeness_m < 0.05 * VOXEL


def test_a_square_beyond_r_max_is_not_seen():
    """R_max 16 cells: the top square, 17 cm away, gives no return, so there is no surface."""
    reconstruction = MeshReconstruction(TwoSquares(), Sensor(60.0, 46.0, 16))
    reconstruction.add_view(np.array([0.24, 0.24, 0.47]), quaternion_from_matrix(np.diag([1.0, -1.0, -1.0])))
    result = reconstruction.chamfer()
    assert result.mesh_vertices == 0 and math.isnan(result.distance_m)
    assert result.describe() == "Chamfer n/a (the TSDF of 1 views has no surface)"


def test_chamfer_needs_a_3d_world_with_meshes():
    flat = World("2d", 0, 0, np.zeros((8, 8), np.uint8), 1.0, np.zeros(2))
    with pytest.raises(ValueError, match="needs a 3D world"):
        MeshReconstruction(flat, Sensor(60.0, None, 8))
    bare = World("3dt", 0, 0, np.zeros((8, 8, 8), np.uint8), 1.0, np.zeros(3))
    with pytest.raises(ValueError, match="has no meshes"):
        MeshReconstruction(bare, Sensor(60.0, 46.0, 8))


def untimed(path) -> list[list[str]]:
    """The rows of a run CSV without its ``time_*`` columns."""
    with open(path, newline="") as handle:
        table = list(csv.reader(handle))
    keep = [i for i, name in enumerate(table[0]) if not name.startswith("time_")]
    return [[row[i] for i in keep] for row in table]


def test_explore_reports_the_chamfer_distance_and_keeps_its_csv(tmp_path, capsys):
    """``nbv explore --chamfer``: the summary line ends with the distance; the run CSV is the one
    written without it, field for field but the planning times."""
    from nbv_prob_cnn.cli import main

    base = ["explore", "--dataset", "3du", "--method", "prob_ig", "--views", "3", "--seed", "120", "--quiet"]
    assert main([*base, "--log", str(tmp_path / "plain.csv")]) == 0
    plain = capsys.readouterr().out
    assert main([*base, "--log", str(tmp_path / "chamfer.csv"), "--chamfer"]) == 0
    line = capsys.readouterr().out
    assert "Chamfer" not in plain and ", Chamfer " in line and "from 3 views)" in line
    assert untimed(tmp_path / "plain.csv") == untimed(tmp_path / "chamfer.csv")
    assert main(["explore", "--dataset", "2d", "--views", "2", "--log", str(tmp_path / "x.csv"), "--chamfer"]) == 2
    assert "--chamfer needs a 3D world" in capsys.readouterr().err


def test_canonical_order_of_a_mesh_listed_in_another_order():
    vertices = np.array([[1.0, 0, 0], [0, 0, 0], [0, 1, 0], [1, 1, 0]])
    triangles = np.array([[1, 0, 2], [0, 3, 2]])
    shuffled = np.array([2, 0, 3, 1])  # new vertex i is old vertex shuffled[i]
    renamed = np.argsort(shuffled)[triangles][::-1]  # the same triangles, listed backwards
    renamed = np.roll(renamed, 1, axis=1)  # and each started at another corner
    a, b = canonical_order(vertices, triangles), canonical_order(vertices[shuffled], renamed)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    # vertices by x, then y, z; triangle (0,0,0) (1,0,0) (0,1,0) keeps its orientation
    np.testing.assert_array_equal(a[0], [[0, 0, 0], [0, 1, 0], [1, 0, 0], [1, 1, 0]])
    np.testing.assert_array_equal(a[1], [[0, 2, 1], [1, 2, 3]])
