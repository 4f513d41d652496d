"""Small pieces every node of ours uses: parameter declaration, QoS, service calls from
callbacks, and a ``main`` that spins and shuts down cleanly."""

from __future__ import annotations

import threading
from collections.abc import Callable

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

#: The grid topic keeps its last message for late joiners and restarted nodes.
GRID_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def descriptor(
    description: str,
    float_range: tuple[float, float] | None = None,
    int_range: tuple[int, int] | None = None,
    dynamic_typing: bool = False,
    read_only: bool = False,
) -> ParameterDescriptor:
    """A parameter descriptor with a description and, optionally, a numeric range."""
    desc = ParameterDescriptor(description=description, dynamic_typing=dynamic_typing, read_only=read_only)
    if float_range is not None:
        desc.floating_point_range = [FloatingPointRange(from_value=float_range[0], to_value=float_range[1], step=0.0)]
    if int_range is not None:
        desc.integer_range = [IntegerRange(from_value=int_range[0], to_value=int_range[1], step=1)]
    return desc


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
    bounds = (min_value, max_value) if min_value is not None and max_value is not None else None
    is_int = isinstance(default, int) and not isinstance(default, bool)
    is_float = isinstance(default, float)
    desc = descriptor(
        description,
        float_range=bounds if is_float else None,
        int_range=(int(bounds[0]), int(bounds[1])) if (bounds and is_int) else None,
        read_only=read_only,
    )
    return node.declare_parameter(name, default, desc).value


def positive_seconds(value) -> None:
    """Validator of :func:`allow_updates` for durations."""
    if not (isinstance(value, float) and value > 0):
        raise ValueError(f"expected a positive number of seconds, got {value!r}")


def allow_updates(node: Node, validators: dict[str, Callable[[object], None]]) -> None:
    """Let the named parameters change at run time: each new value is checked by its
    validator (which raises ``ValueError`` to refuse it) and then set as the node attribute
    of the same name; other parameters stay fixed."""
    from rcl_interfaces.msg import SetParametersResult

    def on_set(params) -> SetParametersResult:
        for param in params:
            if param.name not in validators:
                return SetParametersResult(successful=False, reason=f"{param.name} cannot change at run time")
            try:
                validators[param.name](param.value)
            except ValueError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        for param in params:
            setattr(node, param.name, param.value)
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(on_set)


def declare_subscription_qos(
    node: Node, default_depth: int, what: str, default_reliability: str = "reliable"
) -> QoSProfile:
    """Declare ``queue_size`` and ``qos_reliability`` (``reliable``/``best_effort``) for a node's
    input subscriptions and return the resulting volatile QoS profile (``best_effort`` with
    depth 5 is rclpy's SENSOR_DATA profile).

    Raises:
        ValueError: an unknown reliability name.
    """
    depth = node.declare_parameter(
        "queue_size", default_depth, descriptor(f"depth of the {what}", int_range=(1, 10000))
    ).value
    reliability = node.declare_parameter(
        "qos_reliability",
        default_reliability,
        descriptor(f"{what}: 'reliable' or 'best_effort' (for sensor_data publishers)"),
    ).value
    if reliability not in ("reliable", "best_effort"):
        raise ValueError(f"qos_reliability: expected 'reliable' or 'best_effort', got {reliability!r}")
    return QoSProfile(
        depth=int(depth),
        reliability=ReliabilityPolicy.RELIABLE if reliability == "reliable" else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.VOLATILE,
    )


def call_service(node: Node, client, request, timeout_s: float):
    """Call a service from inside a callback (needs a multi-threaded executor and a reentrant
    callback group on the client). Returns the response.

    Raises:
        TimeoutError: the service is not available or did not answer in time.
    """
    name = node.resolve_service_name(client.srv_name)  # the full name, namespace included
    if not client.wait_for_service(timeout_sec=min(timeout_s, 5.0)):
        raise TimeoutError(f"service {name} is not available")
    done = threading.Event()
    future = client.call_async(request)
    future.add_done_callback(lambda _: done.set())
    if not done.wait(timeout_s):
        client.remove_pending_request(future)
        raise TimeoutError(f"service {name} did not answer within {timeout_s:.1f} s")
    if future.exception() is not None:
        raise RuntimeError(f"service {name} failed: {future.exception()}")
    return future.result()


def run_node(
    factory: Callable[[], Node],
    args: list[str] | None = None,
    *,
    threads: int = 4,
    run: Callable[[Node, object], None] | None = None,
    summary: Callable[[Node], str] | None = None,
    startup_errors: tuple[type[BaseException], ...] = (ValueError, RuntimeError, ParameterException),
    startup_message: str = "cannot start",
) -> int:
    """The ``main`` of every node: ``rclpy.init``, build the node, spin (or ``run(node,
    executor)``) until Ctrl-C or an external shutdown, then destroy the node, log its
    ``summary`` and shut down.

    Returns:
        0, or 1 when building/running the node raised one of ``startup_errors`` (bad
        parameters, unreadable inputs), logged as fatal with ``startup_message``.
    """
    rclpy.init(args=args)
    node = None
    executor = None
    code = 0
    try:
        node = factory()
        executor = MultiThreadedExecutor(num_threads=threads) if threads > 1 else SingleThreadedExecutor()
        executor.add_node(node)
        if run is None:
            executor.spin()
        else:
            run(node, executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as exc:
        if rclpy.ok() and isinstance(exc, startup_errors):
            name = node.get_name() if node is not None else getattr(factory, "__name__", "node")
            rclpy.logging.get_logger(name).fatal(f"{startup_message}: {exc}")
            code = 1
        elif rclpy.ok():
            raise
        # else: interrupted during start-up (SIGINT can surface as another error, e.g. an aborted import)
    finally:
        if executor is not None:
            executor.shutdown()
        if node is not None:
            name = node.get_name()
            node.destroy_node()
            if summary is not None:
                # not the node's logger: its rosout publisher may be gone already (SIGINT shuts the context down)
                rclpy.logging.get_logger(f"{name}.summary").info(summary(node))
        rclpy.try_shutdown()
    return code
