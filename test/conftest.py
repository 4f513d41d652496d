"""Shared test set-up: an isolated cache directory per test session, the DDS environment of ROS
tests, and the default robot of the arm tests."""

import os
import tempfile

import pytest

os.environ.setdefault("NBV_CACHE_DIR", os.path.join(tempfile.gettempdir(), "nbv_prob_cnn_test_cache"))


@pytest.fixture
def rng():
    import numpy as np

    return np.random.default_rng(12345)


#: The DDS settings of :func:`nbv_prob_cnn.ros.graph.ros_environment` that the test process
#: itself needs to meet the nodes it starts.
DDS_KEYS = ("ROS_AUTOMATIC_DISCOVERY_RANGE", "RMW_IMPLEMENTATION", "FASTRTPS_DEFAULT_PROFILES_FILE", "ROS_DOMAIN_ID")


@pytest.fixture
def ros_domain(monkeypatch):
    """Factory: ``ros_domain(domain_id)`` returns the environment for our nodes on that domain
    and gives this test process the same DDS settings (restored after the test)."""
    from nbv_prob_cnn.ros.graph import ros_environment

    def use(domain_id: int) -> dict[str, str]:
        env = ros_environment(domain_id)
        for key in DDS_KEYS:
            monkeypatch.setenv(key, env[key])
        return env

    return use


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
