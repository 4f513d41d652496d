"""``nbv study soak``: keep the simulated graph exploring for a set time while a second client sends a
random mix of valid and invalid requests to every service; report requests, errors, crashes,
dropped frames, memory and file descriptors of every node, and the /dev/shm files left (issue 18).

The graph is the free-flying one of ``launch_scripts/explore_sim.py --no-arm`` (sim_camera,
integrator, completion_server, gain_server, nbv_planner), started by
:class:`~nbv_prob_cnn.ros.graph.NodeGraph` on its own domain. Two client processes run beside
it: :mod:`studies.soak_explorer` (reset the integrator, explore, again) and
:mod:`studies.soak_requester` (the request mix). This process joins no ROS graph: it
samples /proc every ``--sample-period`` seconds and writes ``soak.md``, ``requests.csv``,
``processes.csv`` and ``processes.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

from studies._command import run_command

HELP = "Explore with the simulated graph for a set time under a random mix of valid and invalid requests."

#: The graph's nodes, started in this order (names of the processes and of the node modules).
NODES = ("sim_camera", "integrator", "completion_server", "gain_server", "nbv_planner")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare the command-line options."""
    parser.add_argument("--minutes", type=float, default=30.0, help="soak time (default 30)")
    parser.add_argument("--out", type=Path, default=Path("out/soak"), help="report directory (default out/soak)")
    parser.add_argument("--dataset", default="3du", choices=["3du", "3dt"], help="scene type (default 3du)")
    parser.add_argument("--seed", type=int, default=1000, help="scene seed of sim_camera (default 1000)")
    parser.add_argument("--views", type=int, default=3, help="views per exploration (default 3)")
    parser.add_argument("--method", default="", help="planning method of the explorations (default: the planner's)")
    parser.add_argument("--period", type=float, default=1.0, help="mean pause between random requests [s]")
    parser.add_argument("--request-seed", type=int, default=0, help="seed of the request mix")
    parser.add_argument("--sample-period", type=float, default=10.0, help="/proc sampling period [s] (default 10)")
    parser.add_argument("--request-timeout", type=float, default=60.0, help="longest wait for one answer [s]")
    parser.add_argument("--exploration-timeout", type=float, default=600.0, help="longest exploration [s]")
    parser.add_argument(
        "--grace", type=float, default=300.0,
        help="after the soak time, how long the running exploration and request may take before the clients "
        "are interrupted [s] (default 300)",
    )  # fmt: skip
    parser.add_argument("--domain-id", type=int, help="ROS_DOMAIN_ID (default: derived from the pid)")
    parser.add_argument(
        "--max-growth", type=float, default=0.10,
        help="largest growth of a node's RSS or fds from the end of the first exploration to the end (default 0.10)",
    )  # fmt: skip
    parser.add_argument("--commit", default="", help="the code's commit for the report (default: git rev-parse)")
    parser.add_argument("--note", action="append", default=[], help="a line for the report (e.g. what shared the CPU)")


def _graph_parameters(dataset: str, seed: int) -> dict[str, dict]:
    from nbv_prob_cnn.basics.camera import dataset_defaults

    defaults = dataset_defaults(dataset)
    common = {"dataset": dataset}
    box = {"origin": [0.0, 0.0, 0.0], "shape": list(defaults.shape), "voxel_size": defaults.resolution_m}
    return {
        "sim_camera": {**common, "seed": seed},
        "integrator": box,
        "completion_server": common,
        "gain_server": {**common, "completion": "service"},
        "nbv_planner": common,
    }


def _commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, timeout=10)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True,
                               text=True, timeout=10)  # fmt: skip
        return out.stdout.strip() + (" (with uncommitted changes in the tree)" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def run(args: argparse.Namespace) -> int:
    """Run the soak; 0 when every invariant held, 1 otherwise."""
    from tqdm import tqdm

    from nbv_prob_cnn.basics.camera import dataset_defaults
    from nbv_prob_cnn.ros.graph import NodeGraph, remove_stale_shm, ros_environment
    from studies.soak_report import (
        ProcessSample,
        build_report,
        log_tail,
        read_events,
        sample_process,
        write_report,
    )

    if min(args.minutes, args.views, args.period, args.sample_period, args.request_timeout) <= 0 or args.grace < 0:
        raise ValueError("--minutes, --views, --period, --sample-period and --request-timeout must be positive")
    out: Path = args.out
    logs = out / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    for stale in ("explorer.jsonl", "requests.jsonl"):
        (logs / stale).unlink(missing_ok=True)
    env = ros_environment(args.domain_id)
    domain = int(env["ROS_DOMAIN_ID"])
    spec = dataset_defaults(args.dataset)
    centre = [0.5 * n * spec.resolution_m for n in spec.shape]
    load_start = os.getloadavg()
    started_at = datetime.now(timezone.utc)
    samples: list[ProcessSample] = []
    crashes: list[str] = []
    t0 = time.time()

    def sample(graph: NodeGraph) -> None:
        for name in NODES:
            proc = graph.processes[name]
            with contextlib.suppress(ProcessLookupError):
                rss, fds = sample_process(proc.pid)
                samples.append(ProcessSample(round(time.time() - t0, 2), name, proc.pid, rss, fds))
        graph.note_shm()  # the /dev/shm files the nodes map

    graph = NodeGraph(env, log_dir=logs)
    clients: dict[str, subprocess.Popen] = {}
    print(f"[soak] ROS_DOMAIN_ID={domain}, {args.minutes:g} min, logs in {logs}", flush=True)
    try:
        for name, parameters in _graph_parameters(args.dataset, args.seed).items():
            graph.start_node(name, name, parameters)
        until = t0 + 60.0 * args.minutes
        explorer_cmd = [sys.executable, "-m", "studies.soak_explorer", "--until", str(until),
                        "--events", str(logs / "explorer.jsonl"), "--views", str(args.views),
                        "--method", args.method, "--timeout", str(args.exploration_timeout)]  # fmt: skip
        requester_cmd = [sys.executable, "-m", "studies.soak_requester", "--until", str(until),
                         "--events", str(logs / "requests.jsonl"), "--save-dir", str(logs.resolve()),
                         "--seed", str(args.request_seed), "--period", str(args.period),
                         "--timeout", str(args.request_timeout),
                         "--grid-centre", *(str(c) for c in centre)]  # fmt: skip
        for name, cmd in (("soak_explorer", explorer_cmd), ("soak_requester", requester_cmd)):
            with open(logs / f"{name}.log", "w") as log:
                clients[name] = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT,
                                                 start_new_session=True)  # fmt: skip
        next_sample = time.time()
        dead: set[str] = set()
        with tqdm(total=round(60 * args.minutes), unit="s", desc="soak", mininterval=5.0) as bar:
            while True:
                now = time.time()
                if now >= next_sample:
                    sample(graph)
                    next_sample = now + args.sample_period
                for name, alive in graph.alive().items():
                    if not alive and name not in dead:
                        dead.add(name)
                        code = graph.processes[name].returncode
                        crashes.append(f"{name} exited with {code} after {now - t0:.0f} s, during the soak")
                bar.n = min(round(now - t0), bar.total)
                bar.refresh()
                if all(c.poll() is not None for c in clients.values()):
                    break
                if now > until + args.grace:  # an exploration or a request that does not end
                    break
                time.sleep(0.5)
        sample(graph)  # the end: after the clients finished, before the stop
    except KeyboardInterrupt:
        print("\n[soak] interrupted: stopping the graph and writing the report", flush=True)
    finally:
        for client in clients.values():
            if client.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(client.pid, signal.SIGINT)
                try:
                    client.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    client.kill()
                    client.wait()
        exit_codes: dict[str, int | None] = dict(graph.stop())
    for name, code in exit_codes.items():
        if code not in (0, -signal.SIGINT) and not any(c.startswith(f"{name} ") for c in crashes):
            crashes.append(f"{name} exited with {code} when stopped with SIGINT{log_tail(logs / f'{name}.log')}")
    time.sleep(0.5)
    # what the nodes mapped and is still there; of it, what no process holds is removed, as run_graph does
    shm_files = sorted(n for n in graph.shm_seen if n.startswith("fastrtps") and os.path.exists(f"/dev/shm/{n}"))
    leaked = remove_stale_shm(set(shm_files))
    report = build_report(
        args.minutes, read_events(logs / "requests.jsonl"), read_events(logs / "explorer.jsonl"), samples, t0,
        crashes, exit_codes, shm_files, leaked,
    )  # fmt: skip
    report.max_growth = args.max_growth
    for name, client in clients.items():
        if client.returncode not in (0, None):
            report.notes.append(f"client {name} exited with {client.returncode} (see logs/{name}.log)")
    context = [
        (
            f"`nbv study soak --minutes {args.minutes:g} --dataset {args.dataset} --views {args.views}` started "
            f"{started_at:%Y-%m-%d %H:%M} UTC on commit {args.commit or _commit()}, ROS_DOMAIN_ID {domain}; graph: "
            f"{', '.join(NODES)} (free-flying camera, scene seed {args.seed}); a request every {args.period:g} s "
            f"on average (seed {args.request_seed}); /proc sampled every {args.sample_period:g} s."
        ),
        "",
        (
            f"Machine: {os.cpu_count()} CPU cores; load average {load_start[0]:.2f} at the start, "
            f"{os.getloadavg()[0]:.2f} at the end."
        ),
        *([""] + [f"- {note}" for note in args.note] if args.note else []),
    ]
    title = f"nbv study soak: {args.minutes:g} min, {args.dataset}"
    written = write_report(report, out, title, context)
    violations = report.violations()
    print(f"[soak] wrote {', '.join(str(p) for p in written)}", flush=True)
    for line in violations:
        print(f"[soak] violation: {line}", flush=True)
    return 0 if not violations else 1


def main(argv: list[str] | None = None) -> int:
    """``nbv study soak [args]`` (or ``nbv study soak``)."""
    return run_command("soak", HELP, add_arguments, run, argv)


if __name__ == "__main__":
    raise SystemExit(main())
