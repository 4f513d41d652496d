"""Simulated pinhole depth camera: ray casting of triangle meshes with open3d.

Conventions (docs/method.md: sensor, node graph):
    * Poses are ``world_from_optical`` 4×4 matrices; the optical frame is REP-103
      (x right, y down, z forward).
    * Pixel ``(u, v)`` (column, row) has its centre at image coordinates ``(u, v)``
      (the ROS ``CameraInfo`` / OpenCV convention): a point ``(x, y, z)`` of the optical
      frame projects to ``(fx·x/z + cx, fy·y/z + cy)``.
    * Depth images are ``float32`` metres, **z-depth** along the optical axis (not the
      ray length); ``0`` means "no return".
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from nbv_prob_cnn.sensing.sensor_noise import SensorNoise

__all__ = [
    "ROTATION_TOLERANCE",
    "DepthCamera",
    "DepthNoise",
    "Intrinsics",
    "MeshScene",
    "check_pose",
    "nearest_rotation",
]


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of a depth image (pixels)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ValueError(f"intrinsics: image size must be positive, got {self.width}x{self.height}")
        values = (self.fx, self.fy, self.cx, self.cy)
        if not all(math.isfinite(float(v)) for v in values) or self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"intrinsics: focal lengths must be finite and positive, got fx={self.fx} fy={self.fy}")

    @classmethod
    def from_hfov(cls, width: int = 640, height: int = 480, hfov_deg: float = 60.0) -> Intrinsics:
        """Square pixels, principal point at the image centre, given horizontal field of view."""
        if not 0.0 < hfov_deg < 180.0:
            raise ValueError(f"intrinsics: hfov_deg must lie in (0, 180), got {hfov_deg}")
        focal = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(int(width), int(height), focal, focal, (width - 1) / 2.0, (height - 1) / 2.0)

    @property
    def matrix(self) -> np.ndarray:
        """The 3×3 camera matrix ``K`` (float64)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape ``(height, width)``."""
        return (int(self.height), int(self.width))

    @property
    def fov_deg(self) -> tuple[float, float]:
        """Horizontal and vertical field of view [deg]: the angle between the rays through the
        outer edges of the first and last pixel (pixel centres at integer coordinates, so the
        image spans -0.5 .. width - 0.5), for any principal point."""
        h = math.atan((self.cx + 0.5) / self.fx) + math.atan((self.width - 0.5 - self.cx) / self.fx)
        v = math.atan((self.cy + 0.5) / self.fy) + math.atan((self.height - 0.5 - self.cy) / self.fy)
        return math.degrees(h), math.degrees(v)

    def pixel_rays(self) -> np.ndarray:
        """``(H, W, 3)`` float64 ray directions in the optical frame with unit z component, so a
        ray parameter equals the z-depth."""
        u = (np.arange(self.width, dtype=np.float64) - self.cx) / self.fx
        v = (np.arange(self.height, dtype=np.float64) - self.cy) / self.fy
        uu, vv = np.meshgrid(u, v)
        return np.stack([uu, vv, np.ones_like(uu)], axis=-1)

    def backproject(self, depth_m: np.ndarray) -> np.ndarray:
        """``(N, 3)`` optical-frame points of the valid (finite, > 0) pixels of a depth image."""
        depth = np.asarray(depth_m, dtype=np.float64)
        if depth.shape != self.shape:
            raise ValueError(f"depth: shape {depth.shape} does not match the intrinsics {self.shape}")
        valid = np.isfinite(depth) & (depth > 0)
        return self.pixel_rays()[valid] * depth[valid][:, None]


#: Largest deviation from orthonormality, ``max |R Rᵀ - I|``, of a pose's rotation block that
#: :func:`check_pose` repairs (re-orthonormalises) instead of refusing. Rotations written to text
#: files by real trackers are orthonormal to a few 1e-4 (7-Scenes: 4e-4); 1e-2 (a 0.5 % scale or a
#: 0.6 deg shear at most) still tells rounding from a matrix that is not a rotation at all.
ROTATION_TOLERANCE = 1e-2
#: Deviations up to this are double rounding of an exact rotation: such poses are returned unchanged
#: (bit for bit), so a pose passed through :func:`check_pose` twice stays the same.
ORTHONORMAL_ALREADY = 1e-12


def nearest_rotation(rot: np.ndarray) -> np.ndarray:
    """The rotation closest (Frobenius norm) to a 3×3 matrix of positive determinant: the
    orthonormal factor ``U Vᵀ`` of its polar decomposition (``rot = U S Vᵀ``, SVD).

    Raises:
        ValueError: not 3×3, or a determinant <= 0 (a reflection or a singular matrix, which no
            rotation approximates).
    """
    mat = np.asarray(rot, dtype=np.float64)
    if mat.shape != (3, 3):
        raise ValueError(f"rotation: expected a 3x3 matrix, got shape {mat.shape}")
    if not np.linalg.det(mat) > 0:
        raise ValueError(f"rotation: determinant {np.linalg.det(mat):.6g} is not positive (a reflection or singular)")
    u, _, vt = np.linalg.svd(mat)
    return u @ vt


def check_pose(pose: np.ndarray, name: str = "pose") -> np.ndarray:
    """Validate a rigid 4×4 transform; return it as float64 with an orthonormal rotation block.

    A rotation block within :data:`ROTATION_TOLERANCE` of orthonormal (the rounding of poses read
    from text files or written by trackers) is replaced by the nearest rotation
    (:func:`nearest_rotation`, orthonormal to 1e-15); the translation is kept. One within
    :data:`ORTHONORMAL_ALREADY` is returned as given.

    Raises:
        ValueError: wrong shape, non-finite values, a last row other than ``[0, 0, 0, 1]``, a
            reflection (determinant < 0), or a rotation block farther than the tolerance from
            orthonormal (a scale or shear, named with its deviation).
    """
    mat = np.array(pose, dtype=np.float64)
    if mat.shape != (4, 4):
        raise ValueError(f"{name}: expected a 4x4 matrix, got shape {mat.shape}")
    if not np.all(np.isfinite(mat)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    if not np.allclose(mat[3], [0.0, 0.0, 0.0, 1.0]):
        raise ValueError(f"{name}: last row must be [0, 0, 0, 1], got {mat[3].tolist()}")
    rot = mat[:3, :3]
    deviation = float(np.max(np.abs(rot @ rot.T - np.eye(3))))
    determinant = float(np.linalg.det(rot))
    if determinant < 0:
        raise ValueError(f"{name}: the rotation block is a reflection (determinant {determinant:.6g}), not a rotation")
    if deviation > ROTATION_TOLERANCE:
        raise ValueError(
            f"{name}: the rotation block is not a rotation: max |R R^T - I| = {deviation:.3g} "
            f"exceeds the tolerance {ROTATION_TOLERANCE:g} (a scaled or sheared matrix)"
        )
    if deviation > ORTHONORMAL_ALREADY:
        mat[:3, :3] = nearest_rotation(rot)
    mat[3] = (0.0, 0.0, 0.0, 1.0)
    return mat


@dataclass
class DepthNoise:
    """Depth-proportional Gaussian noise and random pixel dropouts.

    Attributes:
        sigma_per_m: standard deviation of the additive noise per metre of depth
            (``sigma = sigma_per_m * z``).
        dropout: probability that a pixel with a return becomes "no return" (0).
        seed: seed of the generator; the same seed gives the same sequence of noisy images.
    """

    sigma_per_m: float = 0.0
    dropout: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not (self.sigma_per_m >= 0.0 and math.isfinite(self.sigma_per_m)):
            raise ValueError(f"noise: sigma_per_m must be finite and >= 0, got {self.sigma_per_m}")
        if not 0.0 <= self.dropout <= 1.0:
            raise ValueError(f"noise: dropout must lie in [0, 1], got {self.dropout}")
        self._rng = np.random.default_rng(self.seed)

    def apply(self, depth_m: np.ndarray) -> np.ndarray:
        """Return a noisy copy of a ``float32`` depth image (0 stays 0; negatives become 0)."""
        depth = np.array(depth_m, dtype=np.float32, copy=True)
        valid = depth > 0
        if self.sigma_per_m > 0:
            noise = self._rng.standard_normal(depth.shape).astype(np.float32)
            depth = np.where(valid, depth + noise * np.float32(self.sigma_per_m) * depth, np.float32(0))
        if self.dropout > 0:
            drop = self._rng.random(depth.shape) < self.dropout
            depth[drop] = 0.0
        depth[~(depth > 0)] = 0.0
        return depth.astype(np.float32, copy=False)


#: Largest difference of any pose element (rotation entries, metres) at which :meth:`DepthCamera.render`
#: re-uses its last ray cast: far below a pixel (about 1.6e-3 rad at 640 px, 60 deg) and a depth
#: step of float32, far above the rounding of a TF interpolation between two equal samples.
SAME_POSE_TOLERANCE = 1e-9


class MeshScene:
    """Triangle meshes in world metres, ready for ray casting (an open3d ``RaycastingScene``).

    Args:
        meshes: ``trimesh.Trimesh``, ``open3d.geometry.TriangleMesh``,
            ``open3d.t.geometry.TriangleMesh`` or ``(vertices, faces)`` pairs; meshes without
            triangles are skipped.
    """

    def __init__(self, meshes: Sequence[object]) -> None:
        import open3d as o3d  # heavy import, only when a scene is built

        self._scene = o3d.t.geometry.RaycastingScene()
        self.n_meshes = 0
        for mesh in meshes:
            vertices, faces = _mesh_arrays(mesh)
            if len(faces) == 0:
                continue
            self._scene.add_triangles(
                o3d.core.Tensor(np.ascontiguousarray(vertices, dtype=np.float32)),  # type: ignore[call-overload]
                o3d.core.Tensor(np.ascontiguousarray(faces, dtype=np.uint32)),  # type: ignore[call-overload]
            )
            self.n_meshes += 1

    def cast(self, rays: Any) -> tuple[np.ndarray, Any]:
        """Ray parameter of the first hit (``inf`` = none) of each ray of an open3d ``(..., 6)``
        float32 tensor ``[origin, direction]``, and open3d's result (for the hit normals)."""
        result = self._scene.cast_rays(rays)  # type: ignore[call-overload]  # open3d stubs
        return result["t_hit"].numpy(), result


class DepthCamera:
    """Ray-casting depth camera over a fixed set of triangle meshes.

    Args:
        meshes: triangle meshes in world metres (``trimesh.Trimesh``, ``open3d.geometry.TriangleMesh``,
            ``open3d.t.geometry.TriangleMesh`` or ``(vertices, faces)`` pairs), or a
            :class:`MeshScene` built before (used as it is).
        intrinsics: image size and pinhole parameters (default 640×480, 60° HFOV).
        noise: optional :class:`~nbv_prob_cnn.sensing.sensor_noise.SensorNoise` (a sensor model, e.g.
            ``sensor_noise("kinect_v1")``; grazing angles use the ray-cast surface normals) or
            the older :class:`DepthNoise`; off by default (exact depth).
        noise_seed: seed of the generator of a ``SensorNoise`` (same seed, same noisy images).
        depth_min, depth_max: returns outside ``[depth_min, depth_max]`` (z-depth, metres)
            become 0 (no return).
    """

    def __init__(
        self,
        meshes: Sequence[object] | MeshScene,
        intrinsics: Intrinsics | None = None,
        noise: DepthNoise | SensorNoise | None = None,
        depth_min: float = 0.0,
        depth_max: float = math.inf,
        noise_seed: int = 0,
    ) -> None:
        self.intrinsics = intrinsics if intrinsics is not None else Intrinsics.from_hfov()
        self.noise = noise
        self._noise_rng = np.random.default_rng(noise_seed)
        self.depth_min = float(depth_min)
        self.depth_max = float(depth_max)
        self.scene = meshes if isinstance(meshes, MeshScene) else MeshScene(meshes)
        self._rays_optical = self.intrinsics.pixel_rays()
        self._last: tuple | None = None  # (occluder ids, pose, occluders, exact depth, cos incidence)
        self.renders = 0  # ray casts done (a still camera re-uses the last)

    @property
    def n_meshes(self) -> int:
        return self.scene.n_meshes

    def render(self, pose_world_from_optical: np.ndarray, occluders: Sequence[MeshScene] = ()) -> np.ndarray:
        """Depth image ``float32 (H, W)`` in metres (z-depth; 0 = no return) seen from a pose.

        ``occluders`` are further scenes (e.g. a robot arm at its current joint state) seen
        together with the camera's own: each pixel returns the nearest surface of all of them,
        before the depth range and the noise are applied. The exact image of the last call is
        kept: called again from the same pose (every element within :data:`SAME_POSE_TOLERANCE`)
        with the same occluder objects, only the noise is drawn anew (a camera that stands still
        costs no ray casting; :attr:`renders` counts the casts). The tolerance matters for poses
        looked up in TF: interpolating between two equal samples is exact only to the last bits.
        """
        pose = check_pose(pose_world_from_optical, "pose_world_from_optical")
        occluder_ids = tuple(id(o) for o in occluders)
        last = self._last
        if last is not None and last[0] == occluder_ids and np.max(np.abs(pose - last[1])) <= SAME_POSE_TOLERANCE:
            depth, cos_incidence = last[3], last[4]
        else:
            depth, cos_incidence = self._cast(pose, occluders)
            # the occluders kept: their ids stay theirs
            self._last = (occluder_ids, pose.copy(), tuple(occluders), depth, cos_incidence)
        if isinstance(self.noise, SensorNoise):
            return self.noise.apply_image(depth, self._noise_rng, cos_incidence)
        if self.noise is not None:
            return self.noise.apply(depth)
        return depth.copy()

    def _cast(self, pose: np.ndarray, occluders: Sequence[MeshScene]) -> tuple[np.ndarray, np.ndarray | None]:
        """The exact depth (range applied) and, for a ``SensorNoise``, the cosine of each ray's
        incidence on the surface it hits."""
        import open3d as o3d

        self.renders += 1
        directions = self._rays_optical @ pose[:3, :3].T
        origins = np.broadcast_to(pose[:3, 3], directions.shape)
        rays = o3d.core.Tensor(np.concatenate([origins, directions], axis=-1).astype(np.float32))  # type: ignore[call-overload]
        hit, result = self.scene.cast(rays)
        normals = result["primitive_normals"].numpy() if isinstance(self.noise, SensorNoise) else None
        for occluder in occluders:
            occluder_hit, occluder_result = occluder.cast(rays)
            nearer = occluder_hit < hit
            hit = np.where(nearer, occluder_hit, hit)
            if normals is not None:
                normals = np.where(nearer[..., None], occluder_result["primitive_normals"].numpy(), normals)
        depth = np.where(np.isfinite(hit), hit, 0.0).astype(np.float32)
        depth[(depth < self.depth_min) | (depth > self.depth_max)] = 0.0
        if normals is None:
            return depth, None
        unit = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
        return depth, np.abs(np.sum(normals * unit, axis=-1))


def _mesh_arrays(mesh: object) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (V,3), faces (F,3))`` of a supported mesh object."""
    if isinstance(mesh, tuple) and len(mesh) == 2:
        vertices, faces = mesh
    elif hasattr(mesh, "vertices") and hasattr(mesh, "faces"):  # trimesh
        vertices, faces = mesh.vertices, mesh.faces
    elif hasattr(mesh, "vertex") and hasattr(mesh, "triangle"):  # open3d tensor mesh
        vertices, faces = mesh.vertex.positions.numpy(), mesh.triangle.indices.numpy()
    elif hasattr(mesh, "vertices") and hasattr(mesh, "triangles"):  # open3d legacy mesh
        vertices, faces = mesh.vertices, mesh.triangles
    else:
        raise ValueError(f"meshes: unsupported mesh type {type(mesh).__name__}")
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise ValueError("meshes: face indices out of range")
    return vertices, faces


def room_mesh(lower: np.ndarray, upper: np.ndarray):
    """The six walls of an axis-aligned box (a ``trimesh.Trimesh``), seen from inside.

    Put around a scene, every pixel gets a return, so the integrator records free space all the
    way to the edge of its box, as in a lab whose walls lie beyond the planning volume (a
    camera looking into open space would otherwise record nothing there).
    """
    import trimesh

    lower, upper = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    if lower.shape != (3,) or upper.shape != (3,) or np.any(upper <= lower):
        raise ValueError(f"room: expected 3D bounds with lower < upper, got {lower.tolist()} .. {upper.tolist()}")
    box = trimesh.creation.box(extents=upper - lower)
    box.apply_translation((lower + upper) / 2.0)
    box.invert()
    return box
