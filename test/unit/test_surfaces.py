"""Surfaces out (issue 34, item 4): the TSDF's mesh, the occupied cells as a cloud, PLY files, a picture."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("open3d")
trimesh = pytest.importorskip("trimesh")

from nbv_prob_cnn.basics.camera import look_rotation  # noqa: E402
from nbv_prob_cnn.basics.grid import EMPTY, OCCUPIED, UNKNOWN  # noqa: E402
from nbv_prob_cnn.cli import main  # noqa: E402
from nbv_prob_cnn.perception import DepthCamera, Intrinsics, TsdfIntegrator, load_grid  # noqa: E402
from nbv_prob_cnn.perception.surfaces import occupied_centres, render_mesh_png, write_ply  # noqa: E402

VOXEL = 0.0116
SAMPLE_BAG = Path(__file__).resolve().parents[2] / "bags" / "3dt_seed1000_sample"


def test_occupied_centres_by_hand():
    grid = np.full((3, 4, 5), UNKNOWN, dtype=np.int8)
    grid[0, 0, 0] = OCCUPIED
    grid[2, 3, 1] = OCCUPIED
    grid[1, 1, 1] = EMPTY
    points = occupied_centres(grid, np.array([1.0, -2.0, 0.5]), 0.1)
    np.testing.assert_allclose(points, [[1.05, -1.95, 0.55], [1.25, -1.65, 0.65]])


def test_ply_files_read_back_with_another_reader(tmp_path):
    vertices = np.array([[0.0, 0.0, 0.0], [1.5, 0.0, 0.25], [0.0, 2.0, -0.5], [3.0, 1.0, 1.0]])
    triangles = np.array([[0, 1, 2], [1, 3, 2]])
    mesh = trimesh.load(write_ply(tmp_path / "m.ply", vertices, triangles), process=False)
    np.testing.assert_allclose(mesh.vertices, vertices, atol=1e-6)
    np.testing.assert_array_equal(mesh.faces, triangles)
    cloud = trimesh.load(write_ply(tmp_path / "c.ply", vertices), process=False)
    np.testing.assert_allclose(np.asarray(cloud.vertices), vertices, atol=1e-6)
    with pytest.raises(ValueError, match="vertices must be finite"):
        write_ply(tmp_path / "bad.ply", np.array([[0.0, np.nan, 0.0]]))
    with pytest.raises(ValueError, match="triangles must be"):
        write_ply(tmp_path / "bad.ply", vertices, np.array([[0, 1, 4]]))


@pytest.fixture(scope="module")
def tabletop():
    """A table, a box and a sphere in the 3DT box, fused from 8 exact views around them."""
    meshes = [
        trimesh.creation.box(bounds=[[0.10, 0.10, 0.00], [1.38, 1.38, 0.20]]),
        trimesh.creation.box(bounds=[[0.50, 0.55, 0.20], [0.70, 0.75, 0.45]]),
    ]
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.13)
    sphere.apply_translation([0.95, 0.80, 0.33])
    meshes.append(sphere)
    intrinsics = Intrinsics.from_hfov(320, 240, 60.0)
    camera = DepthCamera(meshes, intrinsics)
    integrator = TsdfIntegrator((0.0, 0.0, 0.0), (128, 128, 96), VOXEL)
    target = np.array([0.75, 0.7, 0.3])
    for azimuth in range(0, 360, 45):
        a = math.radians(azimuth)
        pose = np.eye(4)
        pose[:3, 3] = target + [0.7 * math.cos(a), 0.7 * math.sin(a), 0.45]
        pose[:3, :3] = look_rotation(target - pose[:3, 3])
        integrator.integrate(camera.render(pose), intrinsics, pose)
    return meshes, integrator


def test_mesh_lies_on_the_true_surface_in_world_metres(tabletop):
    import open3d as o3d

    meshes, integrator = tabletop
    vertices, triangles = integrator.mesh()
    assert len(triangles) > 5000 and triangles.max() < len(vertices)
    # every vertex inside the box (world metres, not voxels and not the volume frame)
    assert np.all(vertices >= 0.0) and np.all(vertices <= np.array([128, 128, 96]) * VOXEL)
    # distance to the true surface, from open3d's exact point-to-triangle query (not the TSDF)
    scene = o3d.t.geometry.RaycastingScene()
    for mesh in meshes:
        scene.add_triangles(
            o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32)),
            o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)),
        )
    distance = scene.compute_distance(o3d.core.Tensor(vertices.astype(np.float32))).numpy()
    within = float(np.mean(distance <= VOXEL))
    assert within >= 0.95, f"{within:.3f} of the vertices within one cell of the surface"
    # and the surface was found where it was seen: the box top at z = 0.45 m has vertices
    top = np.abs(vertices[:, 2] - 0.45) < VOXEL / 2
    assert np.any(top & (vertices[:, 0] > 0.52) & (vertices[:, 0] < 0.68))


def test_mesh_of_nothing_is_empty():
    vertices, triangles = TsdfIntegrator((0.0, 0.0, 0.0), None, 0.05).mesh()
    assert vertices.shape == (0, 3) and triangles.shape == (0, 3)


def test_integrate_writes_mesh_and_cloud(tmp_path, capsys):
    grid_path, mesh_path, cloud_path = tmp_path / "g.npz", tmp_path / "m.ply", tmp_path / "c.ply"
    args = ["integrate", "--bag", str(SAMPLE_BAG), "--out", str(grid_path), "--mesh", str(mesh_path)]
    assert main([*args, "--cloud", str(cloud_path)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-1].startswith("fused 30 frames")
    assert any(line.startswith("mesh: ") for line in lines) and any(line.startswith("cloud: ") for line in lines)
    grid, origin, voxel = load_grid(grid_path)
    cloud = np.asarray(trimesh.load(cloud_path, process=False).vertices)
    assert len(cloud) == np.count_nonzero(grid == OCCUPIED)
    cells = np.floor((cloud - origin) / voxel).astype(int)
    assert np.all(grid[tuple(cells.T)] == OCCUPIED)
    mesh = trimesh.load(mesh_path, process=False)
    assert len(mesh.faces) > 1000
    # mesh vertices lie next to occupied cells (the surface runs through the occupied band)
    near = np.floor((np.asarray(mesh.vertices) - origin) / voxel).astype(int)
    assert np.mean(grid[tuple(np.clip(near, 0, np.array(grid.shape) - 1).T)] == OCCUPIED) > 0.5
    assert main([*args[:-2], "--mesh", str(tmp_path / "m.obj")]) == 2
    assert "--mesh: expected a .ply file" in capsys.readouterr().err


def test_render_mesh_png_decimates_and_draws(tabletop, tmp_path):
    from PIL import Image

    _, integrator = tabletop
    vertices, triangles = integrator.mesh()
    path = render_mesh_png(tmp_path / "mesh.png", vertices, triangles, title="tabletop", max_triangles=3000)
    with Image.open(path) as image:
        assert image.size[0] > 500 and image.size[1] > 400
        pixels = np.asarray(image.convert("L"))
    assert pixels.std() > 10  # something drawn, not a blank canvas
    with pytest.raises(ValueError, match="no triangles"):
        render_mesh_png(tmp_path / "none.png", vertices, np.zeros((0, 3), dtype=np.int64))
