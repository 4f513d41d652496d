"""Small pieces every node of ours uses: parameter declaration, QoS, waits that wake on cancel
and shutdown (:class:`Interrupt`), service calls from callbacks, and a ``main`` that spins and
shuts down in a safe order (:func:`run_node`)."""

from __future__ import annotations

import contextlib
import signal
import threading
import time
import weakref
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import MISSING, dataclass, field, fields
from typing import Any, TypeVar

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from nbv_prob_cnn.basics.process_heap import (
    HEAP_TRIM_PERIOD_S,
    heap_tuning_enabled,
    limit_heap_retention,
    release_free_heap,
)

ConfigT = TypeVar("ConfigT")

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


@dataclass(frozen=True)
class ParamSpec:
    """How a config field is declared as a ROS parameter (see :func:`param`)."""

    description: str
    min_value: float | None = None
    max_value: float | None = None
    choices: tuple | None = None
    dynamic: bool = False
    check: Callable[[Any], None] | None = None
    attribute: str | None = None


def param(
    default: Any,
    description: str,
    *,
    min_value: float | None = None,
    max_value: float | None = None,
    choices: tuple | None = None,
    dynamic: bool = False,
    check: Callable[[Any], None] | None = None,
    attribute: str | None = None,
) -> Any:
    """A field of a node's config dataclass that is also a ROS parameter of the same name.

    Args:
        default: the default value (its type is the parameter's type; lists are copied).
        description: shown by ``ros2 param describe``; ``choices`` are appended.
        min_value, max_value: numeric range (both or none), enforced by rclpy.
        choices: the allowed values.
        dynamic: may change at run time (otherwise read-only after start-up).
        check: raises ``ValueError`` to refuse a value (at start-up and on every set).
        attribute: the node attribute that mirrors the value (default: the field's name).
    """
    spec = ParamSpec(description, min_value, max_value, choices, dynamic, check, attribute)
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata={"param": spec})
    return field(default=default, metadata={"param": spec})


def check_param(name: str, spec: ParamSpec, value: Any) -> None:
    """Raise ``ValueError`` with a reason when ``value`` is not allowed for parameter ``name``."""
    if spec.choices is not None and value not in spec.choices:
        raise ValueError(f"{name}: expected one of {list(spec.choices)}, got {value!r}")
    if spec.check is not None:
        spec.check(value)


def declare_config(node: Node, config_type: type[ConfigT], *, mirror: bool = True) -> ConfigT:
    """Declare one parameter per field of the dataclass ``config_type`` (fields made with
    :func:`param`) and return the config built from their values.

    As ros2/demos ``set_parameters_callback.py``: an on-set callback only validates (choices,
    ``check``, run-time changes of read-only parameters are refused with a reason) and a post-set
    callback applies accepted values to the config (and, with ``mirror``, to the node attribute
    of the same name, or the spec's ``attribute``).

    Raises:
        ValueError: a start-up value is not allowed (the reason names the parameter).
        rclpy.exceptions.ParameterException: wrong type or out of range (checked by rclpy).
    """
    specs: dict[str, ParamSpec] = {}
    values: dict[str, Any] = {}
    for item in fields(config_type):
        spec: ParamSpec = item.metadata["param"]
        default = item.default if item.default is not MISSING else item.default_factory()  # type: ignore[misc]
        is_int = isinstance(default, int) and not isinstance(default, bool)
        bounds = (spec.min_value, spec.max_value) if spec.min_value is not None else None
        text = spec.description + (f" (one of {list(spec.choices)})" if spec.choices else "")
        desc = descriptor(
            text,
            float_range=bounds if (bounds and isinstance(default, float)) else None,
            int_range=(int(bounds[0]), int(bounds[1])) if (bounds and is_int) else None,
            dynamic_typing=isinstance(default, list),  # [0, 1, 2] for a float list, [] for an empty one
            read_only=not spec.dynamic,
        )
        value = node.declare_parameter(item.name, default, desc).value
        if isinstance(default, list):
            value = list(value)
        check_param(item.name, spec, value)
        specs[item.name], values[item.name] = spec, value
    config = config_type(**values)

    def validate(params) -> SetParametersResult:
        for p in params:
            spec = specs.get(p.name)
            if spec is None:
                continue  # not ours (use_sim_time, ...)
            if not spec.dynamic:
                return SetParametersResult(successful=False, reason=f"{p.name} cannot change at run time")
            try:
                check_param(p.name, spec, p.value)
            except ValueError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def apply(params) -> None:
        for p in params:
            if p.name in specs:
                setattr(config, p.name, p.value)
                if mirror:
                    setattr(node, specs[p.name].attribute or p.name, p.value)

    if mirror:
        for name, value in values.items():
            setattr(node, specs[name].attribute or name, value)
    node.add_on_set_parameters_callback(validate)
    node.add_post_set_parameters_callback(apply)
    return config


def positive_seconds(value) -> None:
    """A ``check`` of :func:`param` for durations."""
    if not (isinstance(value, float) and value > 0):
        raise ValueError(f"expected a positive number of seconds, got {value!r}")


#: Reliability names of :func:`subscription_qos` (``best_effort`` with depth 5 is SENSOR_DATA).
RELIABILITY = ("best_effort", "reliable")


def subscription_qos(depth: int, reliability: str) -> QoSProfile:
    """A volatile keep-last QoS profile for input subscriptions.

    Raises:
        ValueError: an unknown reliability name.
    """
    if reliability not in RELIABILITY:
        raise ValueError(f"qos_reliability: expected one of {list(RELIABILITY)}, got {reliability!r}")
    return QoSProfile(
        depth=int(depth),
        reliability=ReliabilityPolicy.RELIABLE if reliability == "reliable" else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.VOLATILE,
    )


def lost_message_counter(node, counts: dict[str, int], topic: str) -> SubscriptionEventCallbacks:
    """Event callbacks of a subscription that keep ``counts[topic]`` at the number of its messages
    DDS reports lost before delivery (a gap in a best-effort writer's sequence numbers, or samples a
    reliable writer gave up on), and log each new loss (at most every 5 s)."""
    counts[topic] = 0

    def on_lost(status) -> None:
        counts[topic] = int(status.total_count)
        node.get_logger().warning(
            f"{topic}: {status.total_count_change} message(s) lost in transport (DDS); "
            f"{status.total_count} so far", throttle_duration_sec=5.0,
        )  # fmt: skip

    return SubscriptionEventCallbacks(message_lost=on_lost)


class WaitInterruptedError(Exception):
    """A wait ended early because its :class:`Interrupt` was triggered (a goal was canceled, the
    node is shutting down); the message is the interrupt's reason."""


class Interrupt:
    """A one-way flag that wakes every wait made through it at once.

    A callback that waits (for a service reply, a grid, the arm's arrival) waits through an
    interrupt: :meth:`wait_for` on a condition, :meth:`wait_future` on an rclpy future, or
    :meth:`wait_until` on something that can only be polled. :meth:`trigger` (a goal's cancel
    callback, :func:`run_node`'s shutdown) wakes all of them; they raise :class:`WaitInterruptedError`.
    A :meth:`child` is triggered with its parent (a goal's interrupt with the node's).
    """

    def __init__(self, parent: Interrupt | None = None) -> None:
        self._lock = threading.Lock()
        self._reason: str | None = None
        self._wakers: list[Callable[[], None]] = []  # called once when triggered
        self._parent = parent
        if parent is not None and not parent._add_waker(self._follow_parent):
            self._follow_parent()  # the parent was triggered already

    def _follow_parent(self) -> None:
        assert self._parent is not None
        self.trigger(self._parent.reason or "")

    @property
    def reason(self) -> str | None:
        """Why it was triggered; None while it was not."""
        return self._reason

    def is_set(self) -> bool:
        return self._reason is not None

    def trigger(self, reason: str) -> None:
        """Set the flag (the first reason stays) and wake every wait made through it."""
        with self._lock:
            if self._reason is not None:
                return
            self._reason = reason
            wakers, self._wakers = self._wakers, []
        for wake in wakers:
            wake()

    def check(self) -> None:
        """Raise :class:`WaitInterruptedError` when triggered."""
        if self._reason is not None:
            raise WaitInterruptedError(self._reason)

    def child(self) -> Interrupt:
        """An interrupt of its own that this one also triggers (:meth:`release` it when done)."""
        return Interrupt(self)

    def release(self) -> None:
        """A child that is no longer used: its parent stops holding it."""
        if self._parent is not None:
            self._parent._remove_waker(self._follow_parent)

    def _add_waker(self, wake: Callable[[], None]) -> bool:
        """Register ``wake``; False (not registered) when already triggered."""
        with self._lock:
            if self._reason is not None:
                return False
            self._wakers.append(wake)
            return True

    def _remove_waker(self, wake: Callable[[], None]) -> None:
        with self._lock, contextlib.suppress(ValueError):
            self._wakers.remove(wake)

    @contextlib.contextmanager
    def _waking(self, wake: Callable[[], None]) -> Iterator[None]:
        """``wake`` is called if the interrupt is triggered while the block runs."""
        registered = self._add_waker(wake)
        try:
            yield
        finally:
            if registered:
                self._remove_waker(wake)

    def wait_for(self, condition: threading.Condition, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """``condition.wait_for(predicate, timeout_s)`` (call with ``condition`` held) that also
        ends when the interrupt is triggered.

        Returns:
            The predicate's last value (False: timed out).

        Raises:
            WaitInterruptedError: triggered before or while waiting.
        """

        def wake() -> None:
            with condition:
                condition.notify_all()

        with self._waking(wake):
            result = condition.wait_for(lambda: self.is_set() or predicate(), timeout_s)
        self.check()
        return bool(result)

    def wait_future(self, future, timeout_s: float) -> bool:
        """Wait until an rclpy future (completed by the executor's other threads) is done.

        Returns:
            Whether it is done (False: timed out).

        Raises:
            WaitInterruptedError: triggered before or while waiting.
        """
        done = threading.Event()
        future.add_done_callback(lambda _: done.set())
        with self._waking(done.set):
            done.wait(timeout_s)
        self.check()
        return bool(future.done())

    def wait_until(self, predicate: Callable[[], bool], timeout_s: float, period_s: float = 0.05) -> bool:
        """Poll ``predicate`` every ``period_s`` until it holds or ``timeout_s`` passes (for what
        has no notification: a service or action server becoming available).

        Raises:
            WaitInterruptedError: triggered before or while waiting.
        """
        woken = threading.Event()
        deadline = time.monotonic() + timeout_s
        with self._waking(woken.set):
            while True:
                self.check()
                if predicate():
                    return True
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                woken.wait(min(period_s, remaining))


def wait_on(
    condition: threading.Condition, predicate: Callable[[], bool], timeout_s: float, interrupt: Interrupt | None
) -> bool:
    """``condition.wait_for`` (``condition`` held), through ``interrupt`` when there is one."""
    if interrupt is None:
        return condition.wait_for(predicate, timeout_s)
    return interrupt.wait_for(condition, predicate, timeout_s)


_shutdown_interrupts: weakref.WeakKeyDictionary[Node, Interrupt] = weakref.WeakKeyDictionary()
_shutdown_lock = threading.Lock()


def shutdown_interrupt(node: Node) -> Interrupt:
    """The node's shutdown interrupt: :func:`run_node` triggers it first when the node stops, so
    that every wait made through it (or a :meth:`Interrupt.child` of it) ends before the executor
    is joined and the node destroyed."""
    with _shutdown_lock:
        interrupt = _shutdown_interrupts.get(node)
        if interrupt is None:
            interrupt = _shutdown_interrupts[node] = Interrupt()
        return interrupt


def call_service(node: Node, client, request, timeout_s: float, interrupt: Interrupt | None = None):
    """Call a service from inside a callback (needs a multi-threaded executor and a reentrant
    callback group on the client). Returns the response. The wait (for the service, then for
    its answer) ends at once when ``interrupt`` (default: the node's :func:`shutdown_interrupt`)
    is triggered; the pending request is then dropped.

    Raises:
        TimeoutError: the service is not available or did not answer in time.
        WaitInterruptedError: the interrupt was triggered.
    """
    interrupt = interrupt or shutdown_interrupt(node)
    name = node.resolve_service_name(client.srv_name)  # the full name, namespace included
    if not interrupt.wait_until(client.service_is_ready, min(timeout_s, 5.0)):
        raise TimeoutError(f"service {name} is not available")
    future = client.call_async(request)
    try:
        answered = interrupt.wait_future(future, timeout_s)
    except WaitInterruptedError:
        client.remove_pending_request(future)
        raise
    if not answered:
        client.remove_pending_request(future)
        raise TimeoutError(f"service {name} did not answer within {timeout_s:.1f} s")
    if future.exception() is not None:
        raise RuntimeError(f"service {name} failed: {future.exception()}")
    return future.result()


#: Longest time the main thread of :func:`run_node` stays in one wait of the executor, so that a
#: signal (handled by Python between waits) is acted on within this time.
SPIN_PERIOD_S = 0.1
#: At shutdown, how long :func:`run_node` keeps spinning after the shutdown interrupt so that the
#: callbacks it ended can send their answers (service replies, an Explore goal's result).
DRAIN_S = 2.0
#: Then how long it waits for callbacks still running (CPU-bound work) before it gives up
#: destroying the node (destroying it under a running callback can crash the process).
CALLBACK_JOIN_S = 10.0


class SignalStop:
    """SIGINT and SIGTERM stop :func:`run_node`: the first one sets :attr:`received`, and raises
    ``KeyboardInterrupt`` in the main thread unless a :class:`NodeExecutor` is spinning there
    (that one ends its spin within :data:`SPIN_PERIOD_S`, outside any rclpy call). Later signals
    only log, and once the shutdown is done they are ignored: the shutdown that the first one
    started is not cut short. Installed instead of
    rclpy's handler, which shuts the context down from its own thread at once, while callbacks
    still use it and before they could be ended."""

    def __init__(self) -> None:
        self.received: int | None = None
        self.spinning = False  # a NodeExecutor spins in the main thread
        self._previous: dict[int, Any] = {}
        if threading.current_thread() is threading.main_thread():
            for signum in (signal.SIGINT, signal.SIGTERM):
                self._previous[signum] = signal.signal(signum, self._handle)

    def _handle(self, signum: int, _frame) -> None:
        if self.received is None:
            self.received = signum
            if not self.spinning:
                raise KeyboardInterrupt
            return
        rclpy.logging.get_logger("run_node").warning(f"{signal.Signals(signum).name}: already shutting down")

    def ignore_from_now(self) -> None:
        """After the shutdown: the process is about to exit, and a late signal must not raise
        ``KeyboardInterrupt`` during the interpreter's exit (a traceback, exit code 1)."""
        for signum in self._previous:
            signal.signal(signum, signal.SIG_IGN)


class NodeExecutor:
    """What :func:`run_node` adds to rclpy's executors: a :meth:`spin` that waits at most
    :data:`SPIN_PERIOD_S` at a time and ends on a signal (:class:`SignalStop`), a :meth:`drain`
    that spins until the running callbacks have ended, and :meth:`join_callbacks`."""

    signals: SignalStop | None = None

    def spin(self) -> None:
        signals = self.signals
        if signals is not None:
            signals.spinning = True
        try:
            while self.context.ok() and (signals is None or signals.received is None):  # type: ignore[attr-defined]
                self.spin_once(timeout_sec=SPIN_PERIOD_S)  # type: ignore[attr-defined]
        finally:
            if signals is not None:
                signals.spinning = False

    def drain(self, timeout_s: float) -> bool:
        """Callbacks run in the spinning (main) thread: none waits any more once spinning stopped,
        so nothing is run here (a single-threaded node's next callback, a camera frame, would only
        delay the exit)."""
        return True

    def join_callbacks(self, timeout_s: float) -> bool:
        """Callbacks run in the spinning (main) thread: none is running once spinning stopped."""
        return True


class SingleThreadedNodeExecutor(NodeExecutor, SingleThreadedExecutor):
    """rclpy's single-threaded executor with :class:`NodeExecutor`'s spin and drain."""


class MultiThreadedNodeExecutor(NodeExecutor, MultiThreadedExecutor):
    """rclpy's multi-threaded executor with :class:`NodeExecutor`'s spin and drain, and a
    :meth:`join_callbacks` that waits for its worker threads.

    rclpy 7.1.5's ``Executor.shutdown`` returns without waiting for running callbacks (it sets
    ``_is_shutdown`` and then skips the wait that tests it), and ``MultiThreadedExecutor`` never
    joins its worker threads: ``destroy_node`` could run under a callback that still uses the
    node's clients and goal handles. This reads two private attributes of rclpy 7.1.5 (the
    submitted callbacks and the worker pool); without them it falls back to not waiting.
    """

    def running(self) -> list:
        """The callbacks (rclpy tasks) submitted to the worker threads and not finished."""
        return [task for task in list(getattr(self, "_futures", ())) if not task.done()]

    def drain(self, timeout_s: float) -> bool:
        """Spin until the callbacks running now have ended, then until the tasks they left (an
        Explore goal's result response, which rclpy sends from a task of its own) have ended
        too; at most ``timeout_s``. With nothing running it returns after one short round.

        Returns:
            True when everything ended in time.
        """
        deadline = time.monotonic() + timeout_s
        for round_index in range(3):  # what runs now, what it left, what that left
            running = self.running()
            if not running and round_index > 0:
                return True
            while running and time.monotonic() < deadline and self.context.ok():
                self.spin_once(timeout_sec=0.02)
                running = [task for task in running if not task.done()]
            if running:
                return False
            for _ in range(5):  # one callback per spin: let timers pass before the tasks they left
                self.spin_once(timeout_sec=0.01)
        return True

    def join_callbacks(self, timeout_s: float) -> bool:
        """Wait until every worker thread ended (call after spinning stopped).

        Returns:
            True when they all ended within ``timeout_s``.
        """
        pool = getattr(self, "_executor", None)
        if not isinstance(pool, ThreadPoolExecutor):
            return True
        pool.shutdown(wait=False)  # callbacks already queued still run (the node is not destroyed yet)
        deadline = time.monotonic() + timeout_s
        workers = list(getattr(pool, "_threads", ()))
        for worker in workers:
            worker.join(max(0.0, deadline - time.monotonic()))
        return not any(worker.is_alive() for worker in workers)


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
    """The ``main`` of every node: bound the heap's retention of freed memory
    (:func:`~nbv_prob_cnn.basics.process_heap.limit_heap_retention`, logged, and a timer that
    returns the free heap pages every second), ``rclpy.init``,
    build the node, spin (or ``run(node, executor)``) until SIGINT, SIGTERM or an external
    shutdown, then shut down in this order (:func:`shut_down_node`):

    1. trigger the node's :func:`shutdown_interrupt`: every wait made through it ends at once
       (service calls, an exploration's waits);
    2. keep spinning until the callbacks it ended have sent their answers (an Explore goal's
       result, a service's error reply), :data:`DRAIN_S` at most;
    3. wait for the executor's worker threads (:data:`CALLBACK_JOIN_S` at most), stop it;
    4. destroy the node's action servers and clients, then the node (skipped, with an error
       logged, while a callback still runs: destroying it then could crash the process);
    5. log the ``summary``, shut rclpy down.

    rclpy's signal handler is not installed: :class:`SignalStop` takes SIGINT and SIGTERM.

    Returns:
        0, or 1 when building/running the node raised one of ``startup_errors`` (bad
        parameters, unreadable inputs), logged as fatal with ``startup_message``.
    """
    heap = limit_heap_retention()  # before rclpy and the executor start their threads
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    signals = SignalStop()
    node = None
    executor: SingleThreadedNodeExecutor | MultiThreadedNodeExecutor | None = None
    code = 0
    try:
        node = factory()
        node.get_logger().info(heap)
        if heap_tuning_enabled():
            node.create_timer(HEAP_TRIM_PERIOD_S, release_free_heap)
        executor = MultiThreadedNodeExecutor(num_threads=threads) if threads > 1 else SingleThreadedNodeExecutor()
        executor.signals = signals
        executor.add_node(node)
        if run is None:
            executor.spin()
        else:
            run(node, executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as exc:
        stopping = signals.received is not None or not rclpy.ok()
        if not stopping and isinstance(exc, startup_errors):
            name = node.get_name() if node is not None else getattr(factory, "__name__", "node")
            rclpy.logging.get_logger(name).fatal(f"{startup_message}: {exc}")
            code = 1
        elif not stopping:
            raise
        # else: interrupted during start-up (SIGINT can surface as another error, e.g. an aborted import)
    finally:
        try:
            shut_down_node(node, executor, summary)
        finally:
            signals.ignore_from_now()
    return code


def shut_down_node(
    node: Node | None,
    executor: NodeExecutor | None,
    summary: Callable[[Node], str] | None = None,
    drain_s: float = DRAIN_S,
    join_s: float = CALLBACK_JOIN_S,
) -> None:
    """Steps 1-5 of :func:`run_node`'s shutdown (either argument may be None: start-up failed)."""
    if node is not None:
        shutdown_interrupt(node).trigger(f"{node.get_name()} is shutting down")
    joined = True
    if executor is not None:
        if node is not None and rclpy.ok():
            executor.drain(drain_s)
        joined = executor.join_callbacks(join_s)
        executor.shutdown(timeout_sec=0)  # type: ignore[attr-defined]  # after the join: callbacks use its guard
    if node is not None:
        name = node.get_name()
        if joined:
            for waitable in list(node.waitables):  # action servers and clients: destroy_node leaves them
                destroy = getattr(waitable, "destroy", None)
                if destroy is not None:
                    destroy()
            node.destroy_node()
        else:
            rclpy.logging.get_logger(name).error(
                f"a callback still runs {drain_s + join_s:g} s after shutdown began; the node is left to process exit"
            )
        if summary is not None:
            rclpy.logging.get_logger(f"{name}.summary").info(summary(node))
    rclpy.try_shutdown()
