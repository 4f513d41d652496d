"""What a high-rate stream costs a node (``nbv bench --suite ros_streams``): the CPU time a
receiving process spends per ``JointState`` when the subscription is on the node itself (a node
with 8 services, 4 clients and a timer, like ``nbv_planner``, under a ``MultiThreadedExecutor``)
and when it is on the node's :class:`~nbv_prob_cnn.ros.stream_node.StreamNode`, measured one after
the other against the same publisher in one run. Each receiver is its own process (its CPU time
is its own); the publisher runs here."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

#: The receivers: the subscription on the node itself, then on its side node.
MODES = ("node", "stream_node")


def receive(mode: str, seconds: float) -> dict:
    """Run one receiver for ``seconds``; its message count and CPU time (this process)."""
    import rclpy
    from rclpy.callback_groups import ReentrantCallbackGroup
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import JointState
    from std_srvs.srv import Trigger

    from nbv_prob_cnn.ros.stream_node import StreamNode

    rclpy.init()
    node = Node("stream_bench_receiver")
    group = ReentrantCallbackGroup()
    for i in range(8):
        node.create_service(Trigger, f"stream_bench/service{i}", lambda _, response: response, callback_group=group)
    for i in range(4):
        node.create_client(Trigger, f"stream_bench/client{i}", callback_group=group)
    node.create_timer(1.0, lambda: None, callback_group=group)
    count = [0]

    def on_message(_msg) -> None:
        count[0] += 1

    streams = None
    if mode == "node":
        node.create_subscription(JointState, "joint_states", on_message, 10, callback_group=group)
    else:
        streams = StreamNode(node)
        streams.node.create_subscription(JointState, "joint_states", on_message, 10)
    executor = MultiThreadedExecutor(num_threads=4)
    executor.add_node(node)
    deadline = time.monotonic() + 20.0  # discovery: the clock starts with the first message
    while count[0] == 0 and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.1)
    first = count[0]
    start, cpu = time.monotonic(), time.process_time()
    while time.monotonic() - start < seconds:
        executor.spin_once(timeout_sec=0.1)
    cpu = time.process_time() - cpu
    wall = time.monotonic() - start
    count[0] -= first
    if streams is not None:
        streams.destroy()
    executor.shutdown()
    node.destroy_node()
    rclpy.shutdown()
    return {"mode": mode, "messages": count[0], "cpu_s": cpu, "wall_s": wall}


def ros_streams_benchmark(rate_hz: float = 200.0, seconds: float = 10.0) -> str:
    """Both receivers against one publisher at ``rate_hz``; a markdown table."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    from nbv_prob_cnn.ros.graph import ros_environment

    env = ros_environment()
    rclpy.init(domain_id=int(env["ROS_DOMAIN_ID"]))
    publisher_node = Node("stream_bench_publisher")
    publisher = publisher_node.create_publisher(JointState, "joint_states", 10)
    msg = JointState()
    msg.name = [f"panda_joint{i}" for i in range(1, 8)] + ["panda_finger_joint1", "panda_finger_joint2"]
    msg.position = [0.1] * 9
    publisher_node.create_timer(1.0 / rate_hz, lambda: publisher.publish(msg))
    executor = SingleThreadedExecutor()
    executor.add_node(publisher_node)
    rows = []
    try:
        for mode in MODES:
            process = subprocess.Popen(
                [sys.executable, "-m", "nbv_prob_cnn.bench.ros_streams", "--receive", mode, "--seconds", str(seconds)],
                stdout=subprocess.PIPE, text=True, env=env,
            )  # fmt: skip
            while process.poll() is None:
                executor.spin_once(timeout_sec=0.01)
            out = process.stdout.read() if process.stdout else ""
            rows.append(json.loads(out.strip().splitlines()[-1]))
    finally:
        executor.shutdown()
        publisher_node.destroy_node()
        rclpy.shutdown()
    lines = [
        f"JointState at {rate_hz:g} Hz for {seconds:g} s per receiver (the receiver's process CPU time):",
        "",
        "| subscription on | messages | CPU (s) | CPU (% of a core) | CPU per message (ms) |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        per = 1000.0 * r["cpu_s"] / max(r["messages"], 1)
        share = 100 * r["cpu_s"] / r["wall_s"]
        lines.append(f"| {r['mode']} | {r['messages']} | {r['cpu_s']:.2f} | {share:.1f} | {per:.3f} |")
    node, side = rows
    ratio = (node["cpu_s"] / max(node["messages"], 1)) / max(side["cpu_s"] / max(side["messages"], 1), 1e-12)
    lines += ["", f"CPU per message, node / stream_node: {ratio:.1f}x"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--receive", choices=MODES, help="run one receiver (used by the benchmark)")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rate", type=float, default=200.0)
    args = parser.parse_args(argv)
    if args.receive:
        print(json.dumps(receive(args.receive, args.seconds)))
        return 0
    print(ros_streams_benchmark(args.rate, args.seconds))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
