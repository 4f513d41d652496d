"""What the two client processes of ``nbv study soak`` (:mod:`studies.soak_explorer`,
:mod:`studies.soak_requester`) share: a node with its own executor, an Explore action client and a
JSON-lines event log, the options that tell a client when to stop and where to log, and the
run of a client's session (:func:`run_session`)."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import rclpy
from nbv_prob_cnn_msgs.action import Explore
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.action_client import LockedActionClient
from studies.soak_report import EventLog


class SoakClient(Node):
    """A soak client node: spins its own :attr:`executor_`, logs to :attr:`events` and reaches the
    Explore action server through ``_action``."""

    def __init__(self, node_name: str, events: Path) -> None:
        super().__init__(node_name)
        self.events = EventLog(events)
        self.executor_ = SingleThreadedExecutor()
        self.executor_.add_node(self)
        self._action = LockedActionClient(self, Explore, names.EXPLORE)

    def log_event(self, **event) -> None:
        """Append one event (a JSON line) to the event log."""
        self.events.write(**event)

    def destroy_node(self) -> None:
        self.executor_.shutdown()
        super().destroy_node()
        self.events.close()


def client_parser(description: str, until_help: str) -> argparse.ArgumentParser:
    """A client's parser with the options every client takes: ``--until`` (epoch s, described by
    ``until_help``) and ``--events`` (the JSON-lines event log)."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--until", type=float, required=True, help=until_help)
    parser.add_argument("--events", type=Path, required=True, help="JSON-lines event log")
    return parser


def run_session(node: SoakClient, session: Callable[[], int], on_interrupt: Callable[[], None] | None = None) -> int:
    """Run ``session`` on ``node`` and return its exit code (130 on Ctrl-C, after ``on_interrupt``);
    then destroy the node and shut rclpy down."""
    try:
        return session()
    except KeyboardInterrupt:
        if on_interrupt is not None:
            on_interrupt()
        return 130
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
