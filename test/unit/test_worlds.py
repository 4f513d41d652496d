"""World generators (docs/method.md#data-sets): determinism, shapes, occupancy, table and objects, file round trip."""

from __future__ import annotations

import numpy as np
import pytest

from nbv_prob_cnn.worlds import (
    GENERATOR_VERSION,
    World,
    crop,
    generate_city_map,
    generate_dataset,
    generate_world,
    load_or_generate,
    tabletop3d,
    unstructured3d,
    world_cache_path,
    ycb,
)

SHAPES = {"2d": (400, 400), "3du": (64, 64, 64), "3dt": (128, 128, 96)}
OCCUPANCY = {"2d": (0.08, 0.5), "3du": (0.03, 0.3), "3dt": (0.02, 0.2)}


@pytest.fixture(scope="module")
def worlds() -> dict[tuple[str, int], World]:
    """Generated once per module: seeds 0 and 1 of every data set."""
    return {(d, s): generate_world(d, s) for d in SHAPES for s in (0, 1)}


@pytest.mark.parametrize("dataset", sorted(SHAPES))
def test_deterministic_per_seed(worlds, dataset):
    again = generate_world(dataset, 0)
    first = worlds[(dataset, 0)]
    assert np.array_equal(again.ground_truth, first.ground_truth)
    assert [m.name for m in again.meshes] == [m.name for m in first.meshes]
    for a, b in zip(again.meshes, first.meshes, strict=True):
        assert np.array_equal(a.transform, b.transform)
    assert again.table == first.table
    assert not np.array_equal(worlds[(dataset, 1)].ground_truth, first.ground_truth)


@pytest.mark.parametrize("dataset", sorted(SHAPES))
def test_shape_dtype_and_occupancy(worlds, dataset):
    for seed in (0, 1):
        world = worlds[(dataset, seed)]
        assert world.dataset == dataset and world.seed == seed
        assert world.generator_version == GENERATOR_VERSION
        assert world.shape == SHAPES[dataset]
        assert world.ground_truth.dtype == np.uint8
        assert set(np.unique(world.ground_truth)) <= {0, 1}
        assert world.origin.shape == (world.dims,)
        lo, hi = OCCUPANCY[dataset]
        assert lo < world.ground_truth.mean() < hi, world.ground_truth.mean()


def test_2d_world_is_a_crop_of_the_city_map(worlds):
    world = worlds[("2d", 0)]
    assert world.resolution == pytest.approx(1.2)
    assert not world.meshes and not world.table
    city = generate_city_map(0)
    assert city.shape == (1250, 1250) and city.dtype == np.uint8
    assert 0.1 < city.mean() < 0.45
    assert np.array_equal(world.ground_truth, crop(city, 400, np.random.default_rng([0, 1])))


def test_crop():
    city = np.arange(50 * 60).reshape(50, 60)
    a = crop(city, 20, np.random.default_rng(3))
    b = crop(city, 20, np.random.default_rng(3))
    assert a.shape == (20, 20) and np.array_equal(a, b)
    assert np.all(np.diff(a, axis=0) == 60) and np.all(np.diff(a, axis=1) == 1)
    with pytest.raises(ValueError):
        crop(city, 55, np.random.default_rng(0))


def test_3du_objects(worlds):
    box = np.asarray(unstructured3d.SHAPE) * unstructured3d.RESOLUTION
    for seed in (0, 1):
        world = worlds[("3du", seed)]
        assert world.resolution == pytest.approx(0.0116)
        assert 20 <= len(world.meshes) <= 30
        assert len({m.name for m in world.meshes}) == len(world.meshes)
        for mesh in world.triangle_meshes():
            assert np.all(mesh.bounds[0] >= -1e-9) and np.all(mesh.bounds[1] <= box + 1e-9)


def test_3dt_table_and_objects(worlds):
    res = tabletop3d.RESOLUTION
    for seed in (0, 1):
        world = worlds[("3dt", seed)]
        grid = world.ground_truth
        table = world.table
        assert set(table) >= {"height_m", "thickness_m", "noise_m"}
        top = round(table["height_m"] / res)
        assert tabletop3d.TABLE_TOP_CELLS[0] <= top <= tabletop3d.TABLE_TOP_CELLS[1]
        layers = grid.mean(axis=(0, 1))
        assert layers[top - 2] == 1.0  # below the noise: a full layer
        assert layers[top - 1] > 0.8  # the noisy top layer: nearly full
        assert np.all(layers[: top - round(table["thickness_m"] / res)] == 0)  # nothing under the table
        assert 6 <= len(world.meshes) <= 10
        footprints = []
        for placed in world.meshes:
            mesh = ycb.placed_mesh(placed.name, placed.transform)
            # resting on the table, inside the grid
            assert mesh.bounds[0, 2] == pytest.approx(table["height_m"], abs=1e-9)
            assert np.all(mesh.bounds[0] >= 0) and np.all(mesh.bounds[1] <= np.asarray(grid.shape) * res)
            lo, mask = ycb.voxelize(placed.name, placed.transform, grid.shape, res, world.origin)
            cells = np.argwhere(mask) + lo
            assert grid[tuple(cells.T)].all()
            assert cells[:, 2].min() in (top - 1, top)  # touches the table top
            footprints.append({(int(x), int(y)) for x, y in cells[:, :2]})
        for i, a in enumerate(footprints):  # no two objects overlap
            for b in footprints[i + 1 :]:
                assert not a & b
        meshes = world.triangle_meshes()
        assert len(meshes) == len(world.meshes) + 1
        assert meshes[-1].bounds[1, 2] == pytest.approx(table["height_m"] + res)  # raised noise columns
        assert meshes[-1].bounds[1, 0] == pytest.approx(grid.shape[0] * res)


def test_ycb_objects_and_voxelization():
    names = ycb.object_names()
    assert list(names) == sorted(names)
    assert len(names) >= 70
    assert not set(ycb.EXCLUDED) & set(names)
    with pytest.raises(ValueError):
        ycb.load_mesh("no_such_object")
    # a watertight box: the solid voxel count matches its volume (+ surface cells)
    mesh = ycb.load_mesh("036_wood_block")
    res = 0.0116
    transform = np.eye(4)
    transform[:3, 3] = -mesh.bounds[0] + 0.05
    lo, mask = ycb.voxelize("036_wood_block", transform, (32, 32, 32), res, np.zeros(3))
    volume_cells = mesh.volume / res**3
    assert volume_cells < mask.sum() < 1.6 * volume_cells
    # a thin plate is not lost
    lo, mask = ycb.voxelize("029_plate", np.eye(4), (64, 64, 64), res, np.array([-0.3, -0.3, -0.1]))
    assert mask.sum() > 300


def test_save_load_round_trip(worlds, tmp_path):
    for dataset in SHAPES:
        world = worlds[(dataset, 0)]
        path = tmp_path / f"{dataset}.npz"
        world.save(path)
        back = World.load(path)
        assert back.dataset == dataset and back.seed == 0 and back.generator_version == GENERATOR_VERSION
        assert np.array_equal(back.ground_truth, world.ground_truth)
        assert back.resolution == world.resolution and np.array_equal(back.origin, world.origin)
        assert back.table == world.table
        assert [m.name for m in back.meshes] == [m.name for m in world.meshes]
        for a, b in zip(back.meshes, world.meshes, strict=True):
            assert np.allclose(a.transform, b.transform)


def test_bad_arguments():
    with pytest.raises(ValueError, match="unknown dataset"):
        generate_world("4d", 0)
    with pytest.raises(ValueError, match="seed"):
        generate_world("2d", -1)
    with pytest.raises(ValueError):
        generate_city_map(-5)


def test_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("NBV_CACHE_DIR", str(tmp_path))
    path = world_cache_path("2d", 7)
    assert path == tmp_path / "worlds" / "2d" / f"v{GENERATOR_VERSION}" / "7.npz"
    paths = generate_dataset("2d", [7], progress=False)
    assert paths == [path] and path.exists()
    first = load_or_generate("2d", 7)
    assert np.array_equal(first.ground_truth, generate_world("2d", 7).ground_truth)
    path.write_bytes(b"corrupt")  # regenerated, not an error
    assert np.array_equal(load_or_generate("2d", 7).ground_truth, first.ground_truth)


def test_cli_and_preview(tmp_path, capsys):
    from nbv_prob_cnn.cli import main

    out = tmp_path / "scene.npz"
    assert main(["world", "--dataset", "2d", "--seed", "2", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "400 x 400" in printed and "occupied" in printed
    assert out.exists() and out.with_suffix(".png").read_bytes().startswith(b"\x89PNG")
    assert np.array_equal(World.load(out).ground_truth, generate_world("2d", 2).ground_truth)


def test_preview_3d(worlds, tmp_path):
    from nbv_prob_cnn.worlds.preview import save_preview

    path = save_preview(worlds[("3dt", 0)], tmp_path / "p.png")
    assert path.read_bytes().startswith(b"\x89PNG")


def test_3dt_table_mesh_matches_the_grid(worlds):
    import open3d as o3d

    world = worlds[("3dt", 0)]
    res = world.resolution
    scene = o3d.t.geometry.RaycastingScene()
    for mesh in world.triangle_meshes()[-1:]:  # the table alone
        scene.add_triangles(
            o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32)),
            o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)),
        )
    nx, ny, nz = world.shape
    ii, jj = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    rays = np.zeros((nx * ny, 6), dtype=np.float32)
    rays[:, 0], rays[:, 1], rays[:, 2] = (ii.ravel() + 0.5) * res, (jj.ravel() + 0.5) * res, nz * res
    rays[:, 5] = -1.0  # straight down through every column centre
    hit_z = nz * res - scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    occupied = world.ground_truth.reshape(nx * ny, nz)
    column_top = nz - np.argmax(occupied[:, ::-1], axis=1)  # first free cell above the highest occupied one
    under_objects = np.zeros((nx, ny), dtype=bool)
    for placed in world.meshes:
        lo, mask = ycb.voxelize(placed.name, placed.transform, world.shape, res, world.origin)
        cells = np.argwhere(mask) + lo
        under_objects[cells[:, 0], cells[:, 1]] = True
    table_only = ~under_objects.ravel()
    assert table_only.sum() > 0.8 * nx * ny
    np.testing.assert_allclose(hit_z[table_only] / res, column_top[table_only], atol=1e-3)


def test_dataset_for_grid_picks_by_shape():
    from nbv_prob_cnn.basics.datasets import dataset_for_grid

    assert dataset_for_grid((400, 400), "3du") == "2d"  # exact shape, whatever the node's default
    assert dataset_for_grid((64, 64, 64), "3dt") == "3du"
    assert dataset_for_grid((128, 128, 96), "3du") == "3dt"
    assert dataset_for_grid((50, 60), "3dt") == "2d"  # no exact match: the only 2D data set
    assert dataset_for_grid((40, 40, 40), "3dt") == "3dt"  # no exact match: the preferred 3D one
    assert dataset_for_grid((40, 40, 40), "2d") == "3du"  # preferred is 2D: the first 3D one
    with pytest.raises(ValueError, match="no data set has 4D grids"):
        dataset_for_grid((2, 2, 2, 2), "3dt")
