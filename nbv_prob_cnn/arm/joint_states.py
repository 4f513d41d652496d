"""Joint states as a real robot publishes them: one configuration merged from partial messages.

A driver often publishes the arm and the gripper on ``/joint_states`` separately (two
``joint_state_broadcaster``\\ s, or a gripper driver beside the arm driver), names joints the model
does not have (a gripper's drive joint, a conveyor), and leaves joints out. :class:`JointStateMerger`
keeps the latest position of every joint of the model, whichever message brought it:

* names the model lacks are ignored (and reported, so a node can log them once);
* a joint is *missing* only until its first position arrives;
* a malformed message (lengths differ, a name twice, a non-finite position of a known joint) is
  refused as a whole and changes nothing.

No ROS here (the ROS tracker in :mod:`nbv_prob_cnn.ros.robot_params` wraps it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def checked_joint_names(names: Sequence[str], positions: Sequence[float]) -> list[str]:
    """The names of a joint_states message as strings, checked against its positions.

    Raises:
        ValueError: as many names as positions is not the case, or a name appears twice.
    """
    names = [str(name) for name in names]
    if len(names) != len(positions):
        raise ValueError(f"joint_states: {len(names)} joint names but {len(positions)} positions")
    duplicates = sorted({name for name in names if names.count(name) > 1})
    if duplicates:
        raise ValueError(f"joint_states: duplicate joint names {duplicates}")
    return names


class JointStateMerger:
    """The latest position of each of ``joint_names``, merged over partial joint states.

    Args:
        joint_names: the model's joints, in configuration order.
    """

    def __init__(self, joint_names: Sequence[str]) -> None:
        self.joint_names = [str(name) for name in joint_names]
        self._index = {name: i for i, name in enumerate(self.joint_names)}
        self._q = np.zeros(len(self.joint_names), dtype=np.float64)
        self._seen = np.zeros(len(self.joint_names), dtype=bool)
        self.ignored: set[str] = set()  # names seen that the model lacks

    def update(self, names: Sequence[str], positions: Sequence[float]) -> list[str]:
        """Merge one message; returns the names it carried that the model lacks (ignored).

        Raises:
            ValueError: names and positions of different lengths, a duplicate name, or a
                non-finite position of one of the model's joints (nothing is merged then).
        """
        names = checked_joint_names(names, positions)
        known = [(self._index[name], float(value), name) for name, value in zip(names, positions, strict=True)
                 if name in self._index]  # fmt: skip
        bad = [name for _, value, name in known if not math.isfinite(value)]
        if bad:
            raise ValueError(f"joint_states: non-finite positions for joints {bad}")
        for index, value, _ in known:
            self._q[index] = value
            self._seen[index] = True
        unknown = [name for name in names if name not in self._index]
        self.ignored.update(unknown)
        return unknown

    def missing(self) -> list[str]:
        """The model's joints whose position never arrived (configuration order)."""
        return [name for name, seen in zip(self.joint_names, self._seen, strict=True) if not seen]

    def complete(self) -> bool:
        return bool(self._seen.all())

    def configuration(self) -> np.ndarray:
        """The merged configuration ``(n,)``.

        Raises:
            ValueError: joints whose position never arrived (named).
        """
        missing = self.missing()
        if missing:
            raise ValueError(
                f"joint_states: no position received yet for joints {missing} "
                f"(of the robot's {self.joint_names}; ignored names so far: {sorted(self.ignored)})"
            )
        return self._q.copy()


__all__ = ["JointStateMerger"]
