"""Shared test set-up: an isolated cache directory per test session, the DDS environment of ROS
tests, and the default robot of the arm tests."""

import fcntl
import os
import tempfile
from pathlib import Path
from typing import IO

import pytest

os.environ.setdefault("NBV_CACHE_DIR", os.path.join(tempfile.gettempdir(), "nbv_prob_cnn_test_cache"))


@pytest.fixture
def bf16():
    """Skips the test where torch has no bfloat16 convolutions on this CPU (no AVX512 or AMX): the
    opt-in ``cnn_precision="bfloat16"`` is refused there."""
    from nbv_prob_cnn.completion.inference import cpu_has_bfloat16

    if not cpu_has_bfloat16():
        pytest.skip("this CPU has no bfloat16 convolutions (AVX512 or AMX)")


@pytest.fixture
def rng():
    import numpy as np

    return np.random.default_rng(12345)


#: The DDS settings of :func:`nbv_prob_cnn.ros.graph.ros_environment` that the test process
#: itself needs to meet the nodes it starts.
DDS_KEYS = ("ROS_AUTOMATIC_DISCOVERY_RANGE", "RMW_IMPLEMENTATION", "FASTRTPS_DEFAULT_PROFILES_FILE", "ROS_DOMAIN_ID")


#: Lock files of the ROS domains in use by a test on this machine (one per domain).
DOMAIN_LOCKS = Path(tempfile.gettempdir()) / "nbv_ros_domain_locks"
#: Domains 1..232 (0 is everyone's default; above 232 the RTPS ports overflow).
MAX_DOMAIN = 232


def reserve_domain(preferred: int) -> tuple[int, IO[str]]:
    """``preferred``, or the next domain that no other test process on this machine holds, locked
    until the returned file is closed: test sessions that run at the same time (several on one
    machine) never meet in a domain, where one graph's nodes would answer the other's calls and
    publish into its topics (a foreign camera's frames in a test's /camera/pose)."""
    DOMAIN_LOCKS.mkdir(exist_ok=True)
    for offset in range(MAX_DOMAIN):
        domain = 1 + (preferred - 1 + offset) % MAX_DOMAIN
        handle = open(DOMAIN_LOCKS / f"{domain}.lock", "w")  # noqa: SIM115  # held until the test ends
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.close()
            continue
        return domain, handle
    raise RuntimeError(f"no free ROS domain in 1..{MAX_DOMAIN} (locks in {DOMAIN_LOCKS})")


@pytest.fixture
def ros_domain(monkeypatch):
    """Factory: ``ros_domain(domain_id)`` returns the environment for our nodes on that domain (or
    the next one free on this machine: :func:`reserve_domain`) and gives this test process the same
    DDS settings (restored after the test, when the domain is released)."""
    from nbv_prob_cnn.ros.graph import ros_environment

    held: dict[int, IO[str]] = {}  # requested domain -> lock of the domain it got

    def use(domain_id: int) -> dict[str, str]:
        if domain_id not in held:
            domain, held[domain_id] = reserve_domain(domain_id)
        else:
            domain = int(Path(held[domain_id].name).stem)
        env = ros_environment(domain)
        for key in DDS_KEYS:
            monkeypatch.setenv(key, env[key])
        return env

    yield use
    for handle in held.values():
        handle.close()


# ------------------------------------------------------------------ the arm (test_arm, test_arm_unstall)
@pytest.fixture(scope="module")
def robot():
    """The default robot (the Panda beside the 3DT table)."""
    pytest.importorskip("pinocchio")
    from nbv_prob_cnn.arm.robot import RobotModel

    return RobotModel()


@pytest.fixture(scope="module")
def chain(robot):
    from nbv_prob_cnn.arm.kinematics import CameraChain

    return CameraChain(robot)


@pytest.fixture(scope="module")
def checker(robot):
    """Collision checker with sample points 0.75 cells of the 3DT grid apart."""
    from nbv_prob_cnn.arm.collision import CollisionChecker
    from nbv_prob_cnn.basics.camera import DATASETS

    return CollisionChecker(robot, spacing=0.75 * DATASETS["3dt"].resolution_m)


# ------------------------------------------------------------------ tiny City-CNN worlds (test_city_cache, studies)
def _boxes(dataset: str, seed: int):
    """Small environments: 2D 40×40, 3D (3DT layout, 8× lattice) 24×24×16, a few boxes each."""
    import numpy as np

    r = np.random.default_rng(seed)
    shape = (40, 40) if dataset == "2d" else (24, 24, 16)
    grid = np.zeros(shape, dtype=np.uint8)
    for corner in r.integers(0, min(shape) - 4, size=(6, len(shape))):
        grid[tuple(slice(c, c + 4) for c in corner)] = 1
    return grid, 1


@pytest.fixture
def tiny_worlds(tmp_path, monkeypatch):
    """The training data of a temporary cache come from :func:`_boxes` instead of the generators."""
    from nbv_prob_cnn.completion import data as data_mod

    monkeypatch.setenv("NBV_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(data_mod, "load_environment", _boxes)
    monkeypatch.setattr(data_mod, "current_generator_version", lambda: 1)
    return tmp_path
