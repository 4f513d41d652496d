"""A node's ``joint_states`` input: the subscription, the merged configuration
(:class:`~nbv_prob_cnn.ros.robot_params.JointStateTracker`), the log of malformed messages and a
hook for each complete configuration."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import JointState

from nbv_prob_cnn.arm.robot import RobotModel
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.robot_params import JointStateTracker

#: At most one log line per this many seconds about malformed joint states.
ERROR_LOG_PERIOD_S = 5.0


class JointStateIntake(JointStateTracker):
    """A :class:`JointStateTracker` fed by a ``joint_states`` subscription.

    Args:
        robot: the model whose joints are tracked.
        node: logs each malformed message on its logger (at most every :data:`ERROR_LOG_PERIOD_S`).
        subscriber: the node that subscribes (a :class:`~nbv_prob_cnn.ros.stream_node.StreamNode`'s
            side node: joint states come at the robot's rate); default ``node``.
        on_configuration: called with the merged configuration after each valid message once
            every joint has a position (in the subscription's callback).
    """

    def __init__(
        self,
        robot: RobotModel,
        node: Node,
        subscriber: Node | None = None,
        on_configuration: Callable[[np.ndarray], None] | None = None,
    ) -> None:
        super().__init__(robot)
        self._logger = node.get_logger()
        self._on_configuration = on_configuration
        (subscriber or node).create_subscription(JointState, names.JOINT_STATES, self.receive, 10)

    def receive(self, msg: JointState) -> None:
        """Merge ``msg``; log it when malformed, else pass the configuration on."""
        error = self.on_joint_state(msg)
        if error:
            self._logger.error(error, throttle_duration_sec=ERROR_LOG_PERIOD_S)
        elif self._on_configuration is not None:
            try:
                q, _ = self.current()
            except ValueError:  # a joint has not arrived yet (arm and gripper publish apart)
                return
            self._on_configuration(q)
