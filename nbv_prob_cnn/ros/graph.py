"""Start and stop node graphs as separate processes (there is no ``ros2 launch`` here).

Imports no rclpy: used by the launch scripts and the multi-process tests, which also call
services with :func:`call_with_resend`. Every graph gets
localhost-only discovery, its own ``ROS_DOMAIN_ID`` and the Fast DDS shared-memory profile.
"""

from __future__ import annotations

import contextlib
import faulthandler
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO

from nbv_prob_cnn.ros.node_exits import NodeExit, exited_nodes

PROFILE = Path(__file__).with_name("fastdds_shm_profile.xml")
#: The signal on which our nodes write every thread's Python stack into their log (``kill -USR2 <pid>``,
#: :func:`enable_stack_dumps`), even while stuck in native code, where no Python handler runs.
STACK_DUMP_SIGNAL = signal.SIGUSR2
#: Seconds :meth:`NodeGraph.stop` leaves a process to write its stacks before SIGKILL.
STACK_DUMP_WAIT_S = 1.0


def enable_stack_dumps() -> None:
    """Write every thread's Python stack to stderr on :data:`STACK_DUMP_SIGNAL` (:mod:`faulthandler`:
    a native handler, so it works while the main thread waits in C code and Python's own signal
    handlers cannot run). Called by every node's ``main``."""
    faulthandler.register(STACK_DUMP_SIGNAL, all_threads=True)


def ros_environment(domain_id: int | None = None, base: dict | None = None) -> dict[str, str]:
    """Environment for our nodes: localhost discovery, a domain id, the shared-memory profile."""
    env = dict(os.environ if base is None else base)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["RMW_IMPLEMENTATION"] = "rmw_fastrtps_cpp"
    env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(PROFILE)
    env["PYTHONUNBUFFERED"] = "1"
    if domain_id is not None:
        env["ROS_DOMAIN_ID"] = str(domain_id)
    env.setdefault("ROS_DOMAIN_ID", str(free_domain_id()))
    return env


def free_domain_id() -> int:
    """A domain id derived from the process id (1..100), so parallel runs do not meet."""
    return 1 + os.getpid() % 100


def node_command(
    node: str, parameters: dict | None = None, remappings: dict | None = None, namespace: str = ""
) -> list[str]:
    """Command line that runs one of our nodes (``nbv_prob_cnn.ros.<node>``) with parameters,
    remappings and, optionally, a namespace (``/robot1``: every name of the node moves under it)."""
    cmd = [sys.executable, "-m", f"nbv_prob_cnn.ros.{node}", "--ros-args"]
    if namespace:
        cmd += ["-r", f"__ns:={namespace}"]
    for name, value in (parameters or {}).items():
        if isinstance(value, bool):
            value = "true" if value else "false"
        elif isinstance(value, list | tuple):
            value = "[" + ",".join(str(v) for v in value) + "]"
        cmd += ["-p", f"{name}:={value}"]
    for src, dst in (remappings or {}).items():
        cmd += ["-r", f"{src}:={dst}"]
    return cmd


class NodeGraph:
    """A set of node processes started together and stopped together (context manager).

    Stopping sends SIGINT (rclpy shuts down cleanly), then SIGTERM and SIGKILL to whatever is
    still alive after ``grace_s`` (before SIGKILL, :data:`STACK_DUMP_SIGNAL`: its stacks in its log);
    every process is started in its own process group so children are reached too.
    """

    def __init__(self, env: dict[str, str] | None = None, log_dir: str | Path | None = None) -> None:
        self.env = env or ros_environment()
        self.log_dir = Path(log_dir) if log_dir else None
        self.processes: dict[str, subprocess.Popen] = {}
        self.may_exit: set[str] = set()  # processes that end by themselves when done (exit 0), see exited
        self.shm_seen: set[str] = set()  # /dev/shm files the processes mapped (see note_shm)

    def start(self, name: str, command: list[str], may_exit: bool = False) -> subprocess.Popen:
        """Start ``command`` as the process ``name`` (log: ``<log_dir>/<name>.log``). ``may_exit``:
        it ends by itself when its work is done (status 0), which :meth:`exited` does not report."""
        if may_exit:
            self.may_exit.add(name)
        out: IO[str] | int = subprocess.DEVNULL
        if self.log_dir:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            out = open(self.log_dir / f"{name}.log", "w")  # noqa: SIM115 - closed with the process
        proc = subprocess.Popen(command, env=self.env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
        self.processes[name] = proc
        return proc

    def start_node(
        self,
        name: str,
        node: str,
        parameters: dict | None = None,
        remappings: dict | None = None,
        namespace: str = "",
        may_exit: bool = False,
    ):
        return self.start(name, node_command(node, parameters, remappings, namespace), may_exit)

    def alive(self) -> dict[str, bool]:
        return {name: proc.poll() is None for name, proc in self.processes.items()}

    def exited(self) -> list[NodeExit]:
        """The processes that have ended, with their status and last error line, but those
        started with ``may_exit`` that ended with status 0 (:func:`~nbv_prob_cnn.ros.node_exits.exited_nodes`)."""
        return exited_nodes(self.processes, self.log_dir, self.may_exit)

    def note_shm(self) -> set[str]:
        """Add the /dev/shm files the live processes map now to :attr:`shm_seen` (also done by
        :meth:`stop`) and return them."""
        now: set[str] = set()
        for proc in self.processes.values():
            if proc.poll() is None:
                now |= mapped_shm(proc.pid)
        self.shm_seen |= now
        return now

    def stop(self, grace_s: float = 5.0) -> dict[str, int]:
        """Stop every process (noting first the shared memory they map); returns their exit codes.
        A process still running after SIGINT and SIGTERM first gets :data:`STACK_DUMP_SIGNAL`, so
        that its log shows where it hung, then SIGKILL."""
        self.note_shm()
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            running = [p for p in self.processes.values() if p.poll() is None]
            if not running:
                break
            if sig == signal.SIGKILL:
                for proc in running:
                    with contextlib.suppress(ProcessLookupError):
                        os.kill(proc.pid, STACK_DUMP_SIGNAL)
                time.sleep(STACK_DUMP_WAIT_S)
            for proc in running:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, sig)
            deadline = time.monotonic() + grace_s
            while time.monotonic() < deadline and any(p.poll() is None for p in running):
                time.sleep(0.05)
        return {name: proc.wait() for name, proc in self.processes.items()}

    def __enter__(self) -> NodeGraph:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def shm_segments() -> set[str]:
    """Fast DDS shared-memory files in /dev/shm (to check that nothing leaks)."""
    root = Path("/dev/shm")
    return {p.name for p in root.iterdir() if p.name.startswith(("fastrtps_", "fast_datasharing", "sem.fastrtps_"))}


def segment_in_use(name: str, ignore_pids: frozenset[int] = frozenset()) -> bool:
    """Whether a live process maps or holds open ``/dev/shm/<name>``."""
    target = f"/dev/shm/{name}"
    for pid in os.listdir("/proc"):
        if not pid.isdigit() or int(pid) in ignore_pids:
            continue
        try:
            with open(f"/proc/{pid}/maps") as maps:
                if target in maps.read():
                    return True
            for fd in os.listdir(f"/proc/{pid}/fd"):
                if os.readlink(f"/proc/{pid}/fd/{fd}") == target:
                    return True
        except OSError:
            continue
    return False


def mapped_shm(pid: int) -> set[str]:
    """Names of the /dev/shm files process ``pid`` maps or holds open, with the named mutex of
    each Fast DDS port among them (open only while the port is locked); empty when it is gone."""
    names: set[str] = set()
    try:
        with open(f"/proc/{pid}/maps") as maps:
            for line in maps:
                if "/dev/shm/" in line:
                    names.add(line.split("/dev/shm/", 1)[1].split()[0])
        for fd in os.listdir(f"/proc/{pid}/fd"):
            with contextlib.suppress(OSError):
                target = os.readlink(f"/proc/{pid}/fd/{fd}")
                if target.startswith("/dev/shm/"):
                    names.add(target[len("/dev/shm/") :])
    except OSError:
        pass
    return names | {f"sem.{name}_mutex" for name in names if name.startswith("fastrtps_port")}


def remove_stale_shm(names: set[str]) -> list[str]:
    """Remove those of the Fast DDS files ``names`` that still exist and that no live process
    holds (a port's named mutex only with its port); returns the removed names.

    Fast DDS removes a port file when its last user closes it, unless the port was marked
    unhealthy meanwhile; such a file stays after a clean exit (and is replaced by the next
    participant that opens the port). See docs/ros.md, "Shared memory".
    """
    removed = []
    for name in sorted(names):
        if not name.startswith(("fastrtps_", "sem.fastrtps_", "fast_datasharing")):
            continue
        if not os.path.exists(f"/dev/shm/{name}"):
            continue
        port = name[len("sem.") : -len("_mutex")] if name.startswith("sem.") and name.endswith("_mutex") else name
        if segment_in_use(name) or (port != name and segment_in_use(port)):
            continue
        with contextlib.suppress(OSError):
            os.unlink(f"/dev/shm/{name}")
            removed.append(name)
    return removed


def segment_domain(name: str) -> int | None:
    """DDS domain of a port-named segment (RTPS ports are 7400 + 250 * domain + offset), else None."""
    match = re.search(r"port(\d+)", name)
    if match is None:
        return None
    return (int(match.group(1)) - 7400) // 250


def leaked_segments(
    before: set[str], domain: int, ignore_pids: frozenset[int] = frozenset(), among: set[str] | None = None
) -> set[str]:
    """Fast DDS segments created since ``before`` that no live process uses any more; segments of
    other domains (graphs of concurrent test runs) are not ours to judge. ``among``: judge only
    these names (a :class:`NodeGraph`'s :attr:`~NodeGraph.shm_seen`): a segment without a domain in
    its name may be another graph's that ran meanwhile."""
    new = shm_segments() - before if among is None else (shm_segments() - before) & among
    return {name for name in new if segment_domain(name) in (None, domain) and not segment_in_use(name, ignore_pids)}


def hear_ctrl_c() -> None:
    """Let Ctrl-C (SIGINT) raise KeyboardInterrupt in this launcher even when it inherited SIGINT
    ignored: a shell without job control starts background commands (``cmd &``, ``nohup cmd &``)
    that way, and Python then installs no handler, so ``kill -INT`` would go unheard and the
    graph would run on. The processes it starts afterwards get the default disposition."""
    signal.signal(signal.SIGINT, signal.default_int_handler)


#: Exit statuses of the launchers (:func:`run_graph`, ``launch_scripts/*.py``), beside the client's own
#: 0 (done) and 1 (it failed: the graph not ready in time, an exploration or a plan that failed) and
#: argparse's 2 (a bad argument): a node exited while the run needed it (not 3, the ``nbv`` commands'
#: "ran, but the result is empty", README "Exit codes") ...
EXIT_NODE_EXITED = 4
#: ... the run's ``--timeout`` passed (as ``timeout(1)``) ...
EXIT_TIMED_OUT = 124
#: ... Ctrl-C (128 + SIGINT, as a shell reports it).
EXIT_INTERRUPTED = 130
#: How often :func:`watch_graph` looks at the processes [s].
WATCH_PERIOD_S = 0.2
#: How long a stopped client may take to end what it was doing (cancel an exploration) [s].
CLIENT_STOP_S = 15.0


def report_exits(exits: list[NodeExit], label: str) -> None:
    """Tell the user which nodes ended, each with its last error line and log (on stderr)."""
    for node in exits:
        print(f"[{label}] {node.describe()}", file=sys.stderr, flush=True)


def watch_graph(
    graph: NodeGraph,
    client: subprocess.Popen | None,
    label: str,
    deadline: float | None = None,
    timeout_s: float | None = None,
) -> int:
    """Wait until the client ends, a node ends, or ``deadline`` (``time.monotonic``) passes.

    Returns:
        The client's exit status; :data:`EXIT_NODE_EXITED` when a node ended first (or while a
        failing client ended: what it failed on), each reported with its last error line and log;
        :data:`EXIT_TIMED_OUT` at the deadline. Without a client: only the latter two.
    """
    while True:
        status = client.poll() if client is not None else None
        if status == 0:
            return 0
        exits = graph.exited()
        if exits:
            report_exits(exits, label)
            return EXIT_NODE_EXITED
        if status is not None:
            return status
        if deadline is not None and time.monotonic() >= deadline:
            limit = f"--timeout {timeout_s:g} s" if timeout_s is not None else "the time limit"
            print(f"[{label}] {limit} passed (for the whole run, the wait for the graph included)",
                  file=sys.stderr, flush=True)  # fmt: skip
            return EXIT_TIMED_OUT
        time.sleep(WATCH_PERIOD_S)


def stop_client(client: subprocess.Popen, wait_s: float = CLIENT_STOP_S) -> None:
    """Ctrl-C to the client (it cancels what it was doing), SIGKILL after ``wait_s``."""
    if client.poll() is not None:
        return
    with contextlib.suppress(ProcessLookupError):
        client.send_signal(signal.SIGINT)
    try:
        client.wait(timeout=wait_s)
    except subprocess.TimeoutExpired:
        client.kill()
        client.wait()


def run_graph(
    start_nodes: Callable[[NodeGraph], None],
    client_cmd: list[str] | None,
    env: dict[str, str],
    log_dir: str | Path,
    label: str = "graph",
    timeout_s: float | None = None,
) -> int:
    """Start a node graph, run a client process against it (None: serve until Ctrl-C), and stop
    everything.

    The nodes are watched while the client runs (:func:`watch_graph`): when one ends, its last
    error line and log are printed and the run stops at once (a client waiting for the graph
    would wait on a dead one). ``timeout_s`` bounds the whole run, the start of the graph and the
    client's wait for it included. The client runs in its own session, so Ctrl-C reaches only this
    launcher, which forwards it once (the client cancels what it was doing), then stops the nodes
    and removes the shared-memory files they left behind. The launcher itself joins no ROS graph.

    Returns:
        The client's exit status, or :data:`EXIT_NODE_EXITED`, :data:`EXIT_TIMED_OUT`,
        :data:`EXIT_INTERRUPTED` (Ctrl-C).
    """
    deadline = time.monotonic() + timeout_s if timeout_s is not None else None
    domain = int(env["ROS_DOMAIN_ID"])
    previous_sigint = signal.getsignal(signal.SIGINT)
    hear_ctrl_c()
    shm_before = shm_segments()
    graph = NodeGraph(env, log_dir=log_dir)
    print(f"[{label}] ROS_DOMAIN_ID={domain}, logs in {log_dir}", flush=True)
    client: subprocess.Popen | None = None
    code = 1
    try:
        start_nodes(graph)
        if client_cmd is not None:
            client = subprocess.Popen(client_cmd, env=env, start_new_session=True)
        code = watch_graph(graph, client, label, deadline, timeout_s)
        if code in (EXIT_NODE_EXITED, EXIT_TIMED_OUT):
            print(f"[{label}] stopping the graph", file=sys.stderr, flush=True)
    except KeyboardInterrupt:
        print(f"\n[{label}] interrupted: stopping the graph", flush=True)
        code = EXIT_INTERRUPTED
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a (second) Ctrl-C must not cut the clean-up short
        if client is not None:
            stop_client(client)
        codes = graph.stop()
        # files of our stopped processes that nothing uses any more (Fast DDS leaves some port files)
        removed = remove_stale_shm(graph.shm_seen | leaked_segments(shm_before, domain))
        print(f"[{label}] stopped {len(codes)} processes; removed {len(removed)} stale shared-memory files", flush=True)
        if previous_sigint is not None:  # None: a handler not set from Python
            signal.signal(signal.SIGINT, previous_sigint)
    return code


def wait_for(predicate, timeout_s: float, interval_s: float = 0.1) -> bool:
    """Poll ``predicate`` until it returns true or the timeout passes."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval_s)
    return bool(predicate())


def call_with_resend(
    client,
    request,
    timeout_s: float,
    *,
    executor=None,
    resend_s: float = 10.0,
    wait: Callable[[Callable[[], bool], float], bool] | None = None,
    servers: Callable[[], set] | None = None,
    name: str | None = None,
):
    """Call an idempotent service and return its response, sending the request again every
    ``resend_s`` seconds until an answer comes or ``timeout_s`` passes.

    A request sent right after ``wait_for_service`` can be lost while DDS is still matching the
    client with a (re)started server: ``wait_for_service`` reports the server's endpoints before
    the server has matched the client's reply reader, and with volatile durability nothing is
    resent. Waiting once for the whole timeout then fails although the server is up. The answer
    to any of the requests sent is taken: a server slower than ``resend_s`` (a loaded machine)
    answers the first request while the later copies wait in its queue.

    Args:
        client: an rclpy ``Client``.
        request: its request; it is sent as it is each time, so it must be safe to repeat.
        timeout_s: longest wait in total, ``wait_for_service`` included.
        executor: spun here until the answer comes; None when a background thread spins the
            client's node.
        resend_s: wait for one answer at most this long before sending again.
        wait: ``wait(predicate, seconds)`` returns whether ``predicate()`` came to hold within the
            seconds (it may raise to end the call, e.g. on the node's shutdown); used instead of
            ``executor`` and of ``wait_for_service``. Default: polling (:func:`wait_for`).
        servers: the servers' identities now (the request readers' endpoint GIDs): a server that
            was not there at the last send gets the request at once (a restarted server that
            matched this client after the request went out never receives it: volatile
            durability), without waiting ``resend_s``.
        name: the service's name in messages (default: ``client.srv_name``).

    Raises:
        TimeoutError: the service did not appear, or nothing answered within ``timeout_s``.
    """
    deadline = time.monotonic() + timeout_s
    name = name or client.srv_name
    if wait is None:
        appeared = client.wait_for_service(timeout_sec=timeout_s)
    else:
        appeared = wait(client.service_is_ready, timeout_s)
    if not appeared:
        raise TimeoutError(f"service {name} did not appear within {timeout_s:g} s")
    pending: list = []  # every request sent: a slow server's answer to an earlier one counts too
    try:
        while (remaining := deadline - time.monotonic()) > 0:
            known = servers() if servers is not None else set()
            future = client.call_async(request)
            pending.append(future)
            wait_s = min(resend_s, remaining)

            def answered_or_new_server(known: set = known) -> bool:
                return any(f.done() for f in pending) or (servers is not None and not servers() <= known)

            if executor is not None:
                executor.spin_until_future_complete(future, timeout_sec=wait_s)
            elif wait is not None:
                wait(answered_or_new_server, wait_s)
            else:
                wait_for(answered_or_new_server, wait_s, 0.01)
            answered = next((f for f in pending if f.done()), None)
            if answered is not None:
                return answered.result()
    finally:
        for future in pending:
            if not future.done():
                client.remove_pending_request(future)  # unanswered requests no longer wait for a reply
    sent = len(pending)
    raise TimeoutError(f"service {name}: no answer within {timeout_s:g} s ({sent} request(s) sent)")


def send_goal_with_resend(
    client,
    goal,
    timeout_s: float,
    *,
    feedback_callback=None,
    wait: Callable[[Callable[[], bool], float], object] | None = None,
    resend_s: float = 10.0,
):
    """Send an action goal and return its goal handle, sending the same goal (the same goal ID) again
    every ``resend_s`` seconds until an answer comes or ``timeout_s`` passes.

    The goal request is a service call and is lost as :func:`call_with_resend` describes: most often
    the server receives it, starts the goal, and its answer never reaches this client. A copy with the
    same goal ID is then refused as a duplicate (the server never runs one ID twice). So:

    * a copy accepted: that goal handle;
    * every copy sent answered, and refused: the refusal (the goal was refused for its own reason);
    * a later copy refused while an earlier one is unanswered: the server holds the goal (the first copy
      arrived and only its answer was lost): an accepted handle of that goal ID, whose result request
      reaches the running goal. Had the first copy been lost too, the server answers that result request
      at once with status UNKNOWN, and the caller sees that status.

    Args:
        client: an rclpy ``ActionClient`` (``wait_for_server`` is called first).
        goal: the goal message; its copies are identical.
        timeout_s: longest wait in total, ``wait_for_server`` included.
        feedback_callback: as for ``send_goal_async`` (feedback is routed by the goal ID).
        wait: ``wait(predicate, seconds)`` returns when ``predicate()`` holds or the seconds pass,
            spinning the client's node if nothing else does (default: :func:`wait_for`, for a node
            that a background thread spins).
        resend_s: wait for one answer at most this long before sending again.

    Raises:
        TimeoutError: the server did not appear, or nothing answered within ``timeout_s``.
    """
    import uuid

    from rclpy.action.client import ClientGoalHandle
    from unique_identifier_msgs.msg import UUID

    deadline = time.monotonic() + timeout_s
    if not client.wait_for_server(timeout_sec=timeout_s):
        raise TimeoutError(f"action server {client._action_name} did not appear within {timeout_s:g} s")
    goal_id = UUID(uuid=list(uuid.uuid4().bytes))
    pending: list = []
    while (remaining := deadline - time.monotonic()) > 0:
        pending.append(client.send_goal_async(goal, feedback_callback=feedback_callback, goal_uuid=goal_id))
        wait_s = min(resend_s, remaining)
        if wait is None:
            wait_for(lambda: any(f.done() for f in pending), wait_s, 0.01)
        else:
            wait(lambda: any(f.done() for f in pending), wait_s)
        answered = [f.result() for f in pending if f.done()]
        accepted = next((handle for handle in answered if handle.accepted), None)
        if accepted is not None:
            return accepted
        if answered and len(answered) == len(pending):
            return answered[0]  # refused for its own reason
        if answered:  # a duplicate refused: the first copy's goal runs, its answer was lost
            response = client._action_type.Impl.SendGoalService.Response(accepted=True)
            return ClientGoalHandle(client, goal_id, response)
    sent = len(pending)
    raise TimeoutError(f"action {client._action_name}: no answer to the goal within {timeout_s:g} s ({sent} sent)")


__all__ = [
    "EXIT_INTERRUPTED",
    "EXIT_NODE_EXITED",
    "EXIT_TIMED_OUT",
    "NodeGraph",
    "call_with_resend",
    "hear_ctrl_c",
    "leaked_segments",
    "mapped_shm",
    "node_command",
    "remove_stale_shm",
    "ros_environment",
    "run_graph",
    "send_goal_with_resend",
    "shm_segments",
    "stop_client",
    "wait_for",
    "watch_graph",
]
