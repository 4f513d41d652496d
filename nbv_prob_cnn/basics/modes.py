"""The string-valued modes of the library as ``Literal`` types (they accept the same strings as
before, so call sites that pass plain strings keep working; mypy checks them)."""

from __future__ import annotations

from typing import Literal, get_args

#: Gain formulation: probabilistic (equations (2)-(6)) or classic information gain.
GainMode = Literal["prob", "ig"]
#: Where a probabilistic method's occupancy probabilities come from.
ProbabilitySource = Literal["constant", "cnn", "oracle"]
#: Ray-casting backend.
Backend = Literal["auto", "opencl", "numpy"]
#: How ``nbv_planner`` moves the camera: the sim_camera/move_to service, a goal-pose topic, or
#: the arm (arm_sim/move_to_joints with the planned joint goal), or the arm through a
#: joint_trajectory_controller (control_msgs/FollowJointTrajectory with the timed joint path), or
#: MoveIt 2's move_group (moveit_msgs/MoveGroup: the view as a pose or joint goal).
MoveMode = Literal["service", "topic", "arm", "trajectory", "moveit"]
#: Arithmetic of the completion CNN's forward pass: as trained, or bfloat16 under torch's autocast
#: (opt-in: faster on CPUs with AVX512-BF16 or AMX, probabilities within 0.01; docs/performance.md#scale).
CnnPrecision = Literal["float32", "bfloat16"]

GAIN_MODES: tuple[GainMode, ...] = get_args(GainMode)
PROBABILITY_SOURCES: tuple[ProbabilitySource, ...] = get_args(ProbabilitySource)
BACKEND_NAMES: tuple[Backend, ...] = get_args(Backend)
MOVE_MODES: tuple[MoveMode, ...] = get_args(MoveMode)
CNN_PRECISIONS: tuple[CnnPrecision, ...] = get_args(CnnPrecision)
