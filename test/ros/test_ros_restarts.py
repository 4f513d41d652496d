"""Issue 47: servers killed and started again, nodes stopped by SIGINT, on one graph for the module.

* ``completion_server`` and ``gain_server`` are killed (SIGKILL) and started again, 5 times each;
  each time, a plan asked as soon as the new server logs "ready" succeeds at the first request
  (the planner's clients resend to a server that appears after their send: ``call_service``).
* SIGINT to each node, idle and then busy (the planner and the servers with requests in flight,
  the integrator with camera frames arriving): afterwards no Fast DDS file that the node created,
  or that it mapped in the graph's domain, is left in /dev/shm held by no process
  (``shm_release``); a file is judged as the one the node had (:func:`_orphans`).

The graph (``completion_server``, ``gain_server``, ``nbv_planner``, ``integrator``) is started once
for the module (starting it is most of these tests' time); each test first starts again the nodes
that an earlier one stopped (:meth:`RestartGraph.running`), so either runs alone or after the other.
"""

from __future__ import annotations

import json
import os
import re
import signal
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")

from conftest import DDS_KEYS, reserve_domain  # noqa: E402
from geometry_msgs.msg import TransformStamped  # noqa: E402
from nbv_prob_cnn_msgs.msg import VoxelGrid  # noqa: E402
from nbv_prob_cnn_msgs.srv import CompleteGrid, PlanNextBestView, RankViews  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from test_ros_explore import spun_node  # noqa: E402

from nbv_prob_cnn.basics.geometry import GridGeometry  # noqa: E402
from nbv_prob_cnn.ros.conversions import grid_to_msg  # noqa: E402
from nbv_prob_cnn.ros.graph import (  # noqa: E402
    NodeGraph,
    call_with_resend,
    mapped_shm,
    node_command,
    remove_stale_shm,
    ros_environment,
    segment_domain,
    segment_in_use,
    wait_for,
)
from nbv_prob_cnn.ros.qos import GRID_QOS  # noqa: E402
from nbv_prob_cnn.ros.shm_release import own_files  # noqa: E402

pytestmark = pytest.mark.slow  # multi-process ROS graphs

#: The planner's bound on each server call (the issue's runs used 10 s).
SERVICE_TIMEOUT_S = 10.0
#: completion_server without its warm-up inference: "ready" then comes sooner after the service is
#: offered (before the model loads), which leaves the planner's client less time to match the new
#: server before the plan (the race under test), and each of the 6 starts 2-4 s shorter.
SERVERS = {
    "completion_server": {"dataset": "3du", "warm_up": False},
    "gain_server": {"dataset": "3du", "method": "cnn_prob", "backend": "numpy"},
}
NODES = {
    **SERVERS,
    "nbv_planner": {"dataset": "3du", "method": "cnn_prob", "service_timeout_s": SERVICE_TIMEOUT_S},
    # frames posed by /camera/pose, from this test; its grids on a topic of their own (the planner
    # plans on this test's grid)
    "integrator": {"pose_source": "topic", "shape": [32, 32, 32], "voxel_size": 0.02, "publish_rate_hz": 5.0},
}
REMAPS = {"integrator": {"/nbv/grid": "/restarts/integrated_grid"}}
#: A completion server that is ready the moment its service exists (no model to load: probability
#: 0.5 where the grid is unknown), and that logs each request it gets. On the code before the resend
#: (a6097cc), the planner's first request after its start was lost in 17 of 20 restarts (it never
#: reached the server: "service /nbv/complete did not answer within 10.0 s"); with the resend, 0 of 20.
STAND_IN_SERVER = """
import numpy as np
import rclpy
from nbv_prob_cnn_msgs.srv import CompleteGrid
from nbv_prob_cnn.ros.conversions import msg_to_grid, probability_to_msg

rclpy.init()
node = rclpy.create_node("completion_stand_in")

def complete(request, response):
    state, geometry = msg_to_grid(request.grid)
    prob = np.where(state < 0, 0.5, state).astype(np.float32)
    response.probability = probability_to_msg(prob, geometry, request.grid.header.frame_id, request.grid.header.stamp)
    response.success = True
    print("request", flush=True)
    return response

node.create_service(CompleteGrid, "/nbv/complete", complete)
print("ready", flush=True)
rclpy.spin(node)
"""
#: Restarts of the stand-in: on the old code all 3 first plans succeeded in 0.3 % of tries (3/20 cubed).
STAND_IN_ROUNDS = 3
#: SIGINT order in each phase: the planner first (in the busy phase its plans keep both servers busy).
SIGINT_ORDER = ("nbv_planner", "integrator", "completion_server", "gain_server")
#: Requests kept in flight on a busy server: each answer sends the next, so one always waits.
IN_FLIGHT = 2


def _grid() -> VoxelGrid:
    state = np.full((32, 32, 32), -1, dtype=np.int8)
    state[8:24, 8:24, 8:24] = 0
    return grid_to_msg(state, GridGeometry((0.0, 0.0, 0.0), 0.02, state.shape))


class FrameFeed:
    """Depth frames for the integrator at 20 Hz while on: a 48x36 image 0.5 m deep (32FC1), its
    camera_info and /camera/pose (the camera 0.2 m below the grid's centre column, looking up
    +z into it), all with one stamp."""

    def __init__(self, node) -> None:
        self.node, self.on, self.sent = node, False, 0
        self.image = node.create_publisher(Image, "/camera/depth/image", 10)
        self.info = node.create_publisher(CameraInfo, "/camera/depth/camera_info", 10)
        self.pose = node.create_publisher(TransformStamped, "/camera/pose", 10)
        node.create_timer(0.05, self._publish)

    def _publish(self) -> None:
        if not self.on:
            return
        stamp = self.node.get_clock().now().to_msg()
        frame = "camera_depth_optical_frame"
        image = Image(height=36, width=48, encoding="32FC1", step=48 * 4)
        image.data = np.full((36, 48), 0.5, dtype=np.float32).tobytes()
        info = CameraInfo(height=36, width=48, k=[40.0, 0.0, 23.5, 0.0, 40.0, 17.5, 0.0, 0.0, 1.0])
        pose = TransformStamped(child_frame_id=frame)
        pose.header.frame_id = "world"
        pose.transform.translation.x = pose.transform.translation.y = 0.32
        pose.transform.translation.z = -0.2
        pose.transform.rotation.w = 1.0
        for msg in (image, info, pose):
            msg.header.stamp = stamp
        image.header.frame_id = info.header.frame_id = frame
        self.pose.publish(pose)
        self.info.publish(info)
        self.image.publish(image)
        self.sent += 1


class Pressure:
    """Keeps :data:`IN_FLIGHT` requests on ``client`` unanswered: each answer sends the next (a
    busy server). :meth:`in_flight` counts them under the lock the answers take, so it is exact."""

    def __init__(self, client, request) -> None:
        # one request answered first (sent again until then): a client made now, or a server started
        # again since this client's last call, may not have matched yet and lose a first request
        call_with_resend(client, request, 60.0, resend_s=10.0)
        self.client, self.request = client, request
        self.lock = threading.RLock()
        self.sent = self.answered = 0
        self.stopped = False
        self.futures: list = []
        with self.lock:
            for _ in range(IN_FLIGHT):
                self._send()

    def _send(self) -> None:
        future = self.client.call_async(self.request)
        self.sent += 1
        self.futures.append(future)
        future.add_done_callback(self._on_answer)

    def _on_answer(self, future) -> None:
        with self.lock:
            self.answered += 1
            if not self.stopped:
                self._send()

    def in_flight(self) -> tuple[int, int]:
        """(answered, unanswered) now."""
        with self.lock:
            return self.answered, self.sent - self.answered

    def stop(self) -> None:
        with self.lock:
            self.stopped = True
            for future in self.futures:
                if not future.done():
                    self.client.remove_pending_request(future)


class RestartGraph:
    """This module's graph, its client node (spun in the background) and the test's publishers."""

    def __init__(self, node, graph: NodeGraph) -> None:
        self.node, self.graph = node, graph
        self.procs: dict = {}
        self.logs: dict[str, Path] = {}
        self.starts = 0
        self.stand_in = False  # the completion_server running is the stand-in
        self.killed_files: set[tuple[int, int]] = set()  # the files SIGKILLed nodes created (_file_ids)
        self.plan_client = node.create_client(PlanNextBestView, "/nbv/plan")
        self.grid = _grid()
        node.create_publisher(VoxelGrid, "/nbv/grid", GRID_QOS).publish(self.grid)  # latched
        self.frames = FrameFeed(node)

    def start(self, name: str, stand_in: bool = False):
        """Start node ``name`` (a new log each time: ``<name>_<n>.log``); ``stand_in``: the
        :data:`STAND_IN_SERVER` in completion_server's place."""
        self.starts += 1
        log = f"{name}_{self.starts}"
        self.logs[name] = self.graph.log_dir / f"{log}.log"
        if stand_in:
            command = [sys.executable, "-c", STAND_IN_SERVER]
        else:
            command = node_command(name, NODES[name], REMAPS.get(name))
        self.procs[name] = self.graph.start(log, command)
        if name == "completion_server":
            self.stand_in = stand_in
        return self.procs[name]

    def kill(self, name: str) -> None:
        """SIGKILL ``name`` (its files noted first, for the clean-up after the module; those it
        created are left by design, and not judged as a stopped peer's)."""
        self.graph.note_shm()
        self.killed_files |= set(_file_ids(own_files(mapped_shm(self.procs[name].pid))).values())
        os.killpg(self.procs[name].pid, signal.SIGKILL)
        self.procs[name].wait()

    def restart_and_plan(self, name: str, stand_in: bool = False) -> str | None:
        """Kill ``name``, start it again and, as soon as it logs "ready", ask one plan: None when it
        succeeded, else what went wrong."""
        self.kill(name)
        self.start(name, stand_in)
        assert wait_for(lambda: "ready" in self.log(name), 120.0, 0.01), self.log(name)[-2000:]
        reply = self.plan(3 * SERVICE_TIMEOUT_S)
        return None if reply is not None and reply.success else "no reply" if reply is None else reply.message

    def log(self, name: str) -> str:
        return self.logs[name].read_text()

    def plan(self, wait_s: float):
        """One /nbv/plan request, sent once: its reply, or None after ``wait_s``."""
        future = self.plan_client.call_async(PlanNextBestView.Request(top_k=1))
        if not wait_for(future.done, wait_s, 0.01):
            self.plan_client.remove_pending_request(future)
            return None
        return future.result()

    def running(self) -> RestartGraph:
        """Start every node that is not running, and wait until the graph plans."""
        if self.stand_in:
            self.kill("completion_server")
        for name in NODES:
            if name not in self.procs or self.procs[name].poll() is not None:
                self.start(name)
        assert wait_for(self.plan_client.service_is_ready, 120.0, 0.1), "nbv_planner did not come up"

        def planned() -> bool:
            reply = self.plan(3 * SERVICE_TIMEOUT_S)
            return reply is not None and reply.success

        assert wait_for(planned, 180.0, 0.5), "the graph never planned:\n" + self.log("nbv_planner")[-3000:]
        return self

    def pressure(self, name: str) -> Pressure | None:
        """Requests kept in flight on ``name`` (None for the integrator: :class:`FrameFeed`)."""
        if name == "nbv_planner":
            return Pressure(self.plan_client, PlanNextBestView.Request(top_k=1))
        if name == "completion_server":
            client = self.node.create_client(CompleteGrid, "/nbv/complete")
            return Pressure(client, CompleteGrid.Request(grid=self.grid, dataset="3du"))
        if name == "gain_server":
            client = self.node.create_client(RankViews, "/nbv/rank_views")
            return Pressure(client, RankViews.Request(grid=self.grid, method="prob_ig", top_k=1))
        return None

    def integrated(self) -> int:
        """Frames the integrator has integrated (its ``/integrator/diagnostics``)."""
        client = self.node.create_client(Trigger, "/integrator/diagnostics")
        try:
            reply = call_with_resend(client, Trigger.Request(), 30.0, resend_s=3.0)
            return int(json.loads(reply.message)["integrated"])
        finally:
            self.node.destroy_client(client)


@pytest.fixture(scope="module")
def restart_graph(tmp_path_factory):
    domain, lock = reserve_domain(130)  # 130..135: used by no other test module
    env = ros_environment(domain)
    try:
        with pytest.MonkeyPatch.context() as patch:
            for key in DDS_KEYS:
                patch.setenv(key, env[key])
            with spun_node("restarts_test") as node:
                graph = NodeGraph(env, log_dir=tmp_path_factory.mktemp("restarts") / "logs")
                try:
                    yield RestartGraph(node, graph)
                finally:
                    graph.stop()
                    # the files of the SIGKILLed servers (left by design) that nothing holds now
                    remove_stale_shm({n for n in graph.shm_seen if segment_domain(n) in (None, domain)})
    finally:
        lock.close()


def test_a_plan_at_once_after_a_killed_server_is_ready_again_succeeds(restart_graph):
    g = restart_graph.running()
    failures = []
    for name in SERVERS:
        for round_index in range(5):
            failure = g.restart_and_plan(name)
            if failure is not None:
                failures.append(f"{name} restart {round_index + 1}: {failure}")
    assert not failures, "\n".join(failures) + "\n" + g.log("nbv_planner")[-3000:]


def test_a_server_ready_at_once_gets_the_first_request(restart_graph):
    """A completion server that says "ready" as soon as its service exists (the planner's client has
    had no time to match it): the plan asked at once succeeds, each of 3 times."""
    g = restart_graph.running()
    failures = []
    for round_index in range(STAND_IN_ROUNDS):
        failure = g.restart_and_plan("completion_server", stand_in=True)
        if failure is not None:
            requests = g.log("completion_server").splitlines().count("request")
            failures.append(f"stand-in restart {round_index + 1}: {failure} (the stand-in got {requests} request(s))")
    assert not failures, "\n".join(failures) + "\n" + g.log("nbv_planner")[-3000:]


def _judged(mapped: set[str], domain: int) -> set[str]:
    """The files a stopped node answers for: those it created, and the ones of its domain it mapped
    (files of other domains' graphs that it mapped are theirs)."""
    return own_files(mapped) | {name for name in mapped if segment_domain(name) in (None, domain)}


def _file_ids(names: set[str]) -> dict[str, tuple[int, int]]:
    """Each of ``names`` that is in /dev/shm now, with the file it is (device, inode): a file removed
    and made again under the same name is another file."""
    ids = {}
    for name in names:
        try:
            stat = os.stat(f"/dev/shm/{name}")
        except OSError:
            continue
        ids[name] = (stat.st_dev, stat.st_ino)
    return ids


def _orphans(files: dict[str, tuple[int, int]], domain: int) -> list[str]:
    """Those of a stopped node's ``files`` (:func:`_file_ids` while it ran) that are left and held by
    no process. A name of no domain's port range (``fastrtps_port70xx``: each new participant, of any
    domain on the machine, takes the lowest number free) counts only while it is still the node's
    file and no other participant has taken the number (an ``_el`` lock file of the number that is
    not the node's; the new owner opens the port file still there): once the node's files are gone,
    a participant of another test may take the number, and one SIGKILLed leaves its ``_el`` file
    held by no process while its peers still map the port (seen beside a neighbour on domain 154:
    ``fastrtps_port7001_el`` made by its node after the integrator's was removed). The other names
    are this graph's alone (its domain's ports, or unique)."""

    def held(name: str) -> bool:
        if name.startswith("sem.") and name.endswith("_mutex"):
            return segment_in_use(name) or segment_in_use(name[len("sem.") : -len("_mutex")])
        return segment_in_use(name)

    def the_nodes(name: str, file: tuple[int, int]) -> bool:
        if segment_domain(name) in (None, domain):
            return True
        lock = re.sub(r"^(?:sem\.)?(fastrtps_port\d+).*$", r"\1_el", name)
        return file == files[name] and _file_ids({lock}).get(lock) in (None, files.get(lock))

    now = _file_ids({n for n in files if n.startswith(("fastrtps_", "sem.fastrtps_"))})
    return sorted(n for n, file in now.items() if the_nodes(n, file) and not held(n))


def _running(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie, which a container's init may never reap, does not)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def _release_helpers(own: set[str]) -> list[int]:
    """The process ids of the ``shm_release`` processes given any of ``own`` (a node's files)."""
    pids = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            args = Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace").split("\0")
        except OSError:
            continue
        if "nbv_prob_cnn.ros.shm_release" in args and own & set(args):
            pids.append(int(pid))
    return pids


def test_sigint_leaves_no_fast_dds_file_held_by_no_process(restart_graph):
    """Each node stopped in turn while the others run, in an idle graph, then (every node started
    again) in a busy one; the files are judged after each phase, once the stopped nodes' clean-up
    processes have ended (they run while the next nodes are stopped)."""
    g = restart_graph
    domain = int(g.graph.env["ROS_DOMAIN_ID"])
    left: dict[str, list[str]] = {}
    for phase in ("idle", "busy"):
        g.running()  # the idle phase's nodes started again for the busy one
        g.frames.on = phase == "busy"
        if g.frames.on:  # the integrator busy: frames arrive and are integrated, and go on arriving
            assert wait_for(lambda: g.integrated() >= 3, 60.0, 0.5), g.log("integrator")[-2000:]
        judged: dict[str, dict[str, tuple[int, int]]] = {}
        helpers: list[int] = []
        for name in SIGINT_ORDER:
            proc = g.procs[name]
            mapped = mapped_shm(proc.pid)
            files = _file_ids(_judged(mapped, domain))  # the files themselves, while the node has them
            assert any(n.startswith("fastrtps_") for n in own_files(mapped)), f"{name} created no Fast DDS file"
            pressure = g.pressure(name) if phase == "busy" else None
            if pressure is not None:
                assert wait_for(lambda p=pressure: p.in_flight()[0] >= 1, 60.0, 0.05), f"{name} answered nothing"
                assert pressure.in_flight()[1] >= 1, f"{name}: no request in flight"
            sent = g.frames.sent
            os.killpg(proc.pid, signal.SIGINT)
            assert proc.wait(30) == 0, f"{name} ({phase}) exit code: {g.log(name)[-2000:]}"
            if pressure is not None:
                pressure.stop()
            if name == "integrator" and g.frames.on:
                assert wait_for(lambda sent=sent: g.frames.sent > sent, 5.0, 0.01), "no frame sent past the SIGINT"
            judged[name] = {n: file for n, file in files.items() if file not in g.killed_files}
            helpers += _release_helpers(own_files(mapped))  # started before the node exited
        g.frames.on = False
        assert wait_for(lambda h=helpers: not any(map(_running, h)), 30.0, 0.1), "shm_release still runs"
        for name, files in judged.items():  # judged once the nodes' clean-up is over: what is left stays
            if orphans := _orphans(files, domain):
                left[f"{name} ({phase})"] = orphans
    assert not left, f"left in /dev/shm, held by no process: {left}"
