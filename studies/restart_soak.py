"""``nbv study restart_soak``: the simulated graph explores and plans while one server at a time is
killed and started again (issue 47); reports the plans and explorations that failed although no
server was down during them, the /dev/shm files left, and the memory of the long-lived nodes.

The graph is :mod:`studies.soak`'s (sim_camera, integrator, completion_server, gain_server,
nbv_planner; the planner's server calls bounded to ``--service-timeout``). Two clients run beside it:
:mod:`studies.soak_explorer` (reset the integrator, explore, again) and :mod:`studies._restart_plans`
(a plan every ``--plan-period`` s). Every ``--restart-period`` s a server drawn at random
(``--seed``) is stopped, by SIGKILL or SIGINT (drawn too), and started again; the study notes when
its new log says "ready". A server is *down* from its stop to that "ready". Every plan and every
exploration that overlaps no down time must succeed. This process joins no ROS graph.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import random
import re
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from studies._command import run_command

HELP = "Explore and plan with the simulated graph while its servers are killed and started again at random."
#: The servers that are stopped and started again; the other nodes live through the soak.
SERVERS = ("completion_server", "gain_server")
LONG_LIVED = ("sim_camera", "integrator", "nbv_planner")
SIGNALS = {"SIGKILL": signal.SIGKILL, "SIGINT": signal.SIGINT}
#: RSS growth is reported from the first sample this long after the start (the first plans and
#: explorations load the nodes' lazily built state: CNN, ray caster, TF buffers).
WARM_S = 120.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--minutes", type=float, default=10.0, help="soak time (default 10)")
    parser.add_argument("--out", type=Path, default=Path("out/restart_soak"), help="report directory")
    parser.add_argument("--restart-period", type=float, default=30.0, help="one server stopped every so many s")
    parser.add_argument("--plan-period", type=float, default=1.0, help="pause between the plan client's plans [s]")
    parser.add_argument("--service-timeout", type=float, default=10.0, help="the planner's service_timeout_s")
    parser.add_argument("--views", type=int, default=3, help="views per exploration (default 3)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the server and signal draws")
    parser.add_argument("--sample-period", type=float, default=10.0, help="/proc sampling period [s]")
    parser.add_argument("--domain-id", type=int, help="ROS_DOMAIN_ID (default: derived from the pid)")
    parser.add_argument("--note", action="append", default=[], help="a line for the report")


@dataclass
class Restart:
    server: str
    signal: str
    stop_wall: float
    ready_wall: float | None  # None: its "ready" never came


def down_spans(restarts: list[Restart], end_wall: float) -> list[tuple[float, float]]:
    """The times a server was down: from its stop to its new "ready" (to ``end_wall`` without one)."""
    return [(r.stop_wall, r.ready_wall if r.ready_wall is not None else end_wall) for r in restarts]


def overlaps_down(start: float, end: float, down: list[tuple[float, float]]) -> bool:
    """Whether ``[start, end]`` meets any of the ``down`` spans."""
    return any(lo <= end and start <= hi for lo, hi in down)


#: A failure of a server call (the planner's reply naming a service, or no reply at all), as opposed
#: to the planner's answer about its input (no grid yet, nothing seen in it: the explorer resets the
#: integrator before each exploration, and a plan then finds an empty grid).
SERVER_FAILURE = re.compile(r"/nbv/(complete|rank_views)|no answer|did not answer|did not appear|not available")


def outcome(success: bool, message: str) -> str:
    """``ok``; ``refused`` (the planner's answer about its grid); ``failed`` (a server call failed)."""
    if success:
        return "ok"
    return "failed" if SERVER_FAILURE.search(message or "") else "refused"


def judge(events: list[dict[str, Any]], down: list[tuple[float, float]]) -> dict[str, int]:
    """Counts of events (each with ``start_wall``, ``end_wall``, ``outcome``) by whether they overlap
    a down span (``down_``, else ``up_``) and by outcome; ``up_failed`` must be 0."""
    counts = {f"{side}_{kind}": 0 for side in ("up", "down") for kind in ("ok", "refused", "failed")}
    for event in events:
        side = "down" if overlaps_down(event["start_wall"], event["end_wall"], down) else "up"
        counts[f"{side}_{event['outcome']}"] += 1
    return counts


def run(args: argparse.Namespace) -> int:
    from nbv_prob_cnn.ros.graph import NodeGraph, mapped_shm, node_command, remove_stale_shm, ros_environment, wait_for
    from nbv_prob_cnn.ros.shm_release import RELEASE_WAIT_S, own_files
    from studies.soak import NODES, _graph_parameters
    from studies.soak_report import read_events, sample_process

    if min(args.minutes, args.restart_period, args.plan_period, args.service_timeout, args.views) <= 0:
        raise ValueError("--minutes, --restart-period, --plan-period, --service-timeout and --views must be positive")
    out: Path = args.out
    logs = out / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    for stale in ("explorer.jsonl", "plans.jsonl"):
        (logs / stale).unlink(missing_ok=True)
    env = ros_environment(args.domain_id)
    params = _graph_parameters("3du", 1000)
    params["nbv_planner"]["service_timeout_s"] = args.service_timeout
    rng = random.Random(args.seed)
    started_at, load_start, t0 = datetime.now(timezone.utc), os.getloadavg(), time.time()
    until = t0 + 60.0 * args.minutes
    graph = NodeGraph(env, log_dir=logs)
    procs = {name: graph.start_node(name, name, params[name]) for name in NODES}
    rss: dict[str, list[tuple[float, int]]] = {name: [] for name in LONG_LIVED}
    restarts: list[Restart] = []
    killed_files: set[str] = set()  # the own files of SIGKILLed servers: nothing can remove them at their exit
    client_files: set[str] = set()  # the clients' own files (study processes, not our nodes)
    crashes: list[str] = []
    clients: dict[str, subprocess.Popen] = {}
    commands = {
        "soak_explorer": ["-m", "studies.soak_explorer", "--views", str(args.views), "--timeout", "600"],
        "restart_plans": ["-m", "studies._restart_plans", "--period", str(args.plan_period),
                          "--timeout", str(3 * args.service_timeout)],
    }  # fmt: skip
    events = {"soak_explorer": logs / "explorer.jsonl", "restart_plans": logs / "plans.jsonl"}
    print(f"[restart_soak] ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']}, {args.minutes:g} min, logs in {logs}", flush=True)
    try:
        for name, cmd in commands.items():
            with open(logs / f"{name}.log", "w") as log:
                clients[name] = subprocess.Popen(
                    [sys.executable, *cmd, "--until", str(until), "--events", str(events[name])],
                    env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
                )  # fmt: skip
        # the first restart once the graph has planned (the explorer's first exploration ended)
        wait_for(lambda: any(e.get("event") == "exploration" for e in read_events(events["soak_explorer"])), 300.0, 1.0)
        next_restart, next_sample = time.time(), time.time()
        while time.time() < until:
            now = time.time()
            if now >= next_sample:
                for name in LONG_LIVED:
                    with contextlib.suppress(ProcessLookupError):
                        rss[name].append((now - t0, sample_process(procs[name].pid)[0]))
                graph.note_shm()
                for client in clients.values():
                    client_files |= own_files(mapped_shm(client.pid))
                next_sample = now + args.sample_period
            for name in LONG_LIVED:
                if procs[name].poll() is not None and not any(c.startswith(name) for c in crashes):
                    crashes.append(f"{name} exited with {procs[name].returncode} after {now - t0:.0f} s")
            if now >= next_restart:
                server, sig = rng.choice(SERVERS), rng.choice(sorted(SIGNALS))
                graph.note_shm()
                own = own_files(mapped_shm(procs[server].pid))
                stop = time.time()
                os.killpg(procs[server].pid, SIGNALS[sig])
                code = procs[server].wait(60)
                if sig == "SIGKILL":
                    killed_files |= own
                elif code != 0:
                    crashes.append(f"{server} exited with {code} after SIGINT")
                new_log = logs / f"{server}_{len(restarts) + 1}.log"
                procs[server] = graph.start(new_log.stem, node_command(server, params[server]))
                ready = wait_for(lambda new_log=new_log: "ready" in new_log.read_text(), 120.0, 0.01)
                restarts.append(Restart(server, sig, stop, time.time() if ready else None))
                print(f"[restart_soak] {sig} {server} at {stop - t0:.0f} s, ready after "
                      f"{time.time() - stop:.1f} s" if ready else "never ready", flush=True)  # fmt: skip
                next_restart = stop + args.restart_period
            time.sleep(0.05)
        for client in clients.values():
            with contextlib.suppress(subprocess.TimeoutExpired):
                client.wait(timeout=900)
    finally:
        for client in clients.values():
            if client.poll() is None:
                os.killpg(client.pid, signal.SIGINT)
                with contextlib.suppress(subprocess.TimeoutExpired):
                    client.wait(timeout=20)
        end_wall = time.time()
        graph.note_shm()
        exit_codes = graph.stop()
    time.sleep(RELEASE_WAIT_S + 1.0)  # the nodes' shm_release helpers end within this
    mapped = {n for n in graph.shm_seen if n.startswith(("fastrtps_", "sem.fastrtps_"))}
    left_killed = sorted(remove_stale_shm(mapped & killed_files))
    left_clients = sorted(remove_stale_shm(mapped & client_files - killed_files))
    left_other = sorted(remove_stale_shm(mapped - killed_files - client_files))
    down = down_spans(restarts, end_wall)
    plans = [e for e in read_events(events["restart_plans"]) if e.get("event") == "plan"]
    explorations = [e for e in read_events(events["soak_explorer"]) if e.get("event") == "exploration"]
    for plan in plans:
        plan["outcome"] = outcome(plan["success"], plan["message"])
    for exploration in explorations:
        exploration["outcome"] = outcome(exploration["status"] == "succeeded", exploration.get("reason", ""))
    plan_counts, exploration_counts = judge(plans, down), judge(explorations, down)
    failed_up = [e for e in plans + explorations
                 if e["outcome"] != "ok" and not overlaps_down(e["start_wall"], e["end_wall"], down)]  # fmt: skip
    stopped_badly = {n: c for n, c in exit_codes.items() if c not in (0, -signal.SIGKILL, -signal.SIGINT)}
    lines = [
        f"# nbv study restart_soak: {args.minutes:g} min",
        "",
        (
            f"`{' '.join(['nbv study restart_soak', *_ARGV])}`, started {started_at:%Y-%m-%d %H:%M} UTC; "
            f"{os.cpu_count()} CPU cores, load average {load_start[0]:.2f} at the start, "
            f"{os.getloadavg()[0]:.2f} at the end."
        ),
        *[f"- {note}" for note in args.note],
        "",
        f"Restarts: {len(restarts)} ({', '.join(f'{r.signal} {r.server}' for r in restarts)}); "
        f'down from the stop to the new "ready": '
        + (", ".join(f"{hi - lo:.1f}" for lo, hi in down) + " s" if down else "none"),
        "",
        (
            "Outcomes: ok; refused (the planner's answer about its grid: none yet, or nothing seen in it after the "
            "explorer's integrator reset); **failed** (a server call failed or nothing answered)."
        ),
        "",
        (
            "| | no server down meanwhile: ok | refused | **failed (must be 0)** | a server down meanwhile: ok "
            "| refused | failed |"
        ),
        "|---|---|---|---|---|---|---|",
        *[
            f"| {label} | {c['up_ok']} | {c['up_refused']} | **{c['up_failed']}** | {c['down_ok']} | "
            f"{c['down_refused']} | {c['down_failed']} |"
            for label, c in (("plans (one request each)", plan_counts), ("explorations", exploration_counts))
        ],
        "",
        *[
            f"- {e['outcome']} with no server down: {e.get('message') or e.get('reason')}"
            for e in failed_up
            if e["outcome"] == "failed"
        ],  # fmt: skip
        "",
        (
            f"/dev/shm after the stop (and {RELEASE_WAIT_S:g} s for the nodes' clean-up), held by no process: "
            f"**{len(left_other)}** files of the live or SIGINT-stopped nodes (must be 0){': ' if left_other else ''}"
            f"{', '.join(left_other)}; {len(left_killed)} files of the SIGKILLed servers' own (no process can remove "
            f"its own files on SIGKILL; removed here, as `run_graph` does); {len(left_clients)} of the study's "
            "client processes (not our nodes; removed here)."
        ),
        "",
        (
            f"| long-lived node | RSS at the first sample [MiB] | after {WARM_S:g} s | at the end | growth after "
            f"{WARM_S:g} s |"
        ),
        "|---|---|---|---|---|",
        *[
            f"| {name} | {s[0][1] / 1024:.0f} (at {s[0][0]:.0f} s) | {warm[1] / 1024:.0f} (at {warm[0]:.0f} s) | "
            f"{s[-1][1] / 1024:.0f} (at {s[-1][0]:.0f} s) | {(s[-1][1] - warm[1]) / warm[1]:+.1%} |"
            for name, s in rss.items()
            if s
            for warm in [next((t for t in s if t[0] >= WARM_S), s[-1])]
        ],  # fmt: skip
        "",
        (
            f"Crashes: {'; '.join(crashes) or 'none'}; exit codes at the stop other than 0 or a signal: "
            f"{stopped_badly or 'none'}."
        ),
    ]
    (out / "restart_soak.md").write_text("\n".join(lines) + "\n")
    with open(out / "rss.csv", "w") as table:  # every sample, for a plot or a later look
        table.write("node,time_s,rss_kib\n")
        table.writelines(f"{name},{t:.1f},{kib}\n" for name, samples in rss.items() for t, kib in samples)
    print("\n".join(lines), flush=True)
    violations = plan_counts["up_failed"] + exploration_counts["up_failed"] + len(left_other) + len(crashes)
    return 0 if violations == 0 and not stopped_badly else 1


_ARGV: list[str] = []


def main(argv: list[str] | None = None) -> int:
    _ARGV[:] = sys.argv[1:] if argv is None else argv  # the command line, for the report
    return run_command("restart_soak", HELP, add_arguments, run, argv)


if __name__ == "__main__":
    raise SystemExit(main())
