"""Small pieces every node of ours uses: parameter declaration, QoS, service calls from
callbacks, and a ``main`` that spins and shuts down cleanly."""

from __future__ import annotations

import threading
from collections.abc import Callable

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

#: The grid topic keeps its last message for late joiners and restarted nodes.
GRID_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def declare(
    node: Node,
    name: str,
    default,
    description: str,
    *,
    min_value: float | None = None,
    max_value: float | None = None,
    read_only: bool = False,
):
    """Declare a parameter with a description (and a numeric range) and return its value."""
    descriptor = ParameterDescriptor(description=description, read_only=read_only)
    if min_value is not None and max_value is not None:
        if isinstance(default, bool):
            pass
        elif isinstance(default, int):
            descriptor.integer_range = [IntegerRange(from_value=int(min_value), to_value=int(max_value), step=0)]
        elif isinstance(default, float):
            descriptor.floating_point_range = [
                FloatingPointRange(from_value=float(min_value), to_value=float(max_value), step=0.0)
            ]
    return node.declare_parameter(name, default, descriptor).value


def call_service(node: Node, client, request, timeout_s: float):
    """Call a service from inside a callback (needs a multi-threaded executor and a reentrant
    callback group on the client). Returns the response.

    Raises:
        TimeoutError: the service is not available or did not answer in time.
    """
    if not client.wait_for_service(timeout_sec=min(timeout_s, 5.0)):
        raise TimeoutError(f"service {client.srv_name} is not available")
    done = threading.Event()
    future = client.call_async(request)
    future.add_done_callback(lambda _: done.set())
    if not done.wait(timeout_s):
        client.remove_pending_request(future)
        raise TimeoutError(f"service {client.srv_name} did not answer within {timeout_s:.1f} s")
    if future.exception() is not None:
        raise RuntimeError(f"service {client.srv_name} failed: {future.exception()}")
    return future.result()


def run_node(factory: Callable[[], Node], args: list[str] | None = None, threads: int = 4) -> int:
    """``rclpy.init``, build the node, spin a multi-threaded executor until Ctrl-C or an external
    shutdown, then destroy the node and shut down. Returns the process exit code."""
    rclpy.init(args=args)
    node = None
    try:
        node = factory()
        executor = MultiThreadedExecutor(num_threads=threads)
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
