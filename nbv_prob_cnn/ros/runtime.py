"""How our nodes run: a ``main`` that spins and shuts down in a safe order (:func:`run_node`,
:func:`shut_down_node`, the executors and :class:`SignalStop`), the node's shutdown interrupt
(:func:`shutdown_interrupt`) and service calls from callbacks that end on it (:func:`call_service`)."""

from __future__ import annotations

import signal
import threading
import time
import weakref
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from nbv_prob_cnn.basics.interrupt import Interrupt, WaitInterruptedError
from nbv_prob_cnn.basics.process_heap import (
    HEAP_TRIM_PERIOD_S,
    heap_tuning_enabled,
    limit_heap_retention,
    release_free_heap,
)
from nbv_prob_cnn.ros.graph import call_with_resend, enable_stack_dumps
from nbv_prob_cnn.ros.shm_release import note_own_files, release_after_exit

NodeT = TypeVar("NodeT", bound=Node)

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


#: :func:`call_service` sends a request again when no answer came within this many times the
#: client's last answer time (at least :data:`RESEND_MIN_S`; before a first answer: half the timeout).
RESEND_FACTOR = 3.0
RESEND_MIN_S = 2.0
_answer_s: weakref.WeakKeyDictionary[Any, float] = weakref.WeakKeyDictionary()


def service_servers(node: Node, name: str) -> set[bytes]:
    """The endpoint GIDs of the servers of service ``name`` (full name) in ``node``'s graph: the
    readers of its request topic; empty while the node's graph cannot be read (shutting down)."""
    try:
        infos = node.get_subscriptions_info_by_topic(f"rq{name}Request", no_mangle=True)
    except Exception:  # noqa: BLE001 - rclpy's errors of a context being shut down vary
        return set()
    return {bytes(info.endpoint_gid) for info in infos}


def call_service(node: Node, client, request, timeout_s: float, interrupt: Interrupt | None = None):
    """Call a service from inside a callback (needs a multi-threaded executor and a reentrant
    callback group on the client). Returns the response. ``timeout_s`` bounds the whole call: the
    wait for the service, then for an answer to the request or to a copy of it
    (:func:`~nbv_prob_cnn.ros.graph.call_with_resend`): a copy goes out at once when a server
    appears that was not there at the last send (a restarted server), and after
    :data:`RESEND_FACTOR` times the client's last answer time without an answer (a request or its
    answer lost while DDS matched the two). The waits end at once when ``interrupt`` (default:
    the node's :func:`shutdown_interrupt`) is triggered; the pending requests are then dropped.

    Raises:
        TimeoutError: the service is not available or did not answer in time.
        WaitInterruptedError: the interrupt was triggered.
    """
    interrupt = interrupt or shutdown_interrupt(node)
    name = node.resolve_service_name(client.srv_name)  # the full name, namespace included
    last = _answer_s.get(client)
    resend_s = timeout_s / 2 if last is None else max(RESEND_MIN_S, RESEND_FACTOR * last)
    start = time.monotonic()
    try:
        reply = call_with_resend(
            client, request, timeout_s, resend_s=resend_s, wait=interrupt.wait_until,
            servers=lambda: service_servers(node, name), name=name,
        )  # fmt: skip
    except (TimeoutError, WaitInterruptedError):
        raise
    except Exception as exc:  # noqa: BLE001 - the future's exception
        raise RuntimeError(f"service {name} failed: {exc}") from exc
    _answer_s[client] = time.monotonic() - start
    return reply


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
    factory: Callable[[], NodeT],
    args: list[str] | None = None,
    *,
    threads: int = 4,
    run: Callable[[NodeT, Any], None] | None = None,
    summary: Callable[[NodeT], str] | None = None,
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
    5. log the ``summary``, shut rclpy down;
    6. hand the Fast DDS files the process created to a detached process that removes them once
       no process holds them (:mod:`~nbv_prob_cnn.ros.shm_release`).

    rclpy's signal handler is not installed: :class:`SignalStop` takes SIGINT and SIGTERM.
    SIGUSR2 writes every thread's stack into the log (:func:`~nbv_prob_cnn.ros.graph.enable_stack_dumps`).

    Returns:
        0, or 1 when building/running the node raised one of ``startup_errors`` (bad
        parameters, unreadable inputs), logged as fatal with ``startup_message``.
    """
    enable_stack_dumps()  # kill -USR2: every thread's stack in the log, also when stuck in native code
    heap = limit_heap_retention()  # before rclpy and the executor start their threads
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    signals = SignalStop()
    node: NodeT | None = None
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
        own_shm = note_own_files()  # before the participant closes them
        try:
            shut_down_node(node, executor, summary)
        finally:
            signals.ignore_from_now()
            release_after_exit(own_shm)  # Fast DDS's own removal of them misses some (issue 47)
    return code


def shut_down_node(
    node: NodeT | None,
    executor: NodeExecutor | None,
    summary: Callable[[NodeT], str] | None = None,
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
