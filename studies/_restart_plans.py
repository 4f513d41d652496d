"""The planning client of ``nbv study restart_soak``: until a set time, asks ``/nbv/plan`` every
``--period`` seconds (each request sent once, answered or not within ``--timeout``) and logs each
plan, with its start and end, as one JSON line. Run by :mod:`studies.restart_soak` as its own process."""

from __future__ import annotations

import time

import rclpy
from nbv_prob_cnn_msgs.srv import PlanNextBestView

from nbv_prob_cnn.ros import names
from studies._soak_client import SoakClient, client_parser, run_session


def main(argv: list[str] | None = None) -> int:
    parser = client_parser("Plan every --period seconds until --until (nbv study restart_soak).",
                           "stop starting plans then (epoch s)")  # fmt: skip
    parser.add_argument("--period", type=float, default=1.0, help="pause between plans [s]")
    parser.add_argument("--timeout", type=float, default=60.0, help="longest wait for one answer [s]")
    parser.add_argument("--ready-timeout", type=float, default=300.0)
    args = parser.parse_args(argv)
    rclpy.init()
    node = SoakClient("restart_plans", args.events)
    client = node.create_client(PlanNextBestView, names.PLAN)

    def plan_again_and_again() -> int:
        if not client.wait_for_service(timeout_sec=args.ready_timeout):
            node.log_event(event="error", message=f"no /nbv/plan within {args.ready_timeout:g} s")
            return 1
        while time.time() < args.until:
            start = time.time()
            future = client.call_async(PlanNextBestView.Request(top_k=1))
            node.executor_.spin_until_future_complete(future, timeout_sec=args.timeout)
            if future.done():
                reply = future.result()
                success, message = bool(reply.success), reply.message
            else:
                client.remove_pending_request(future)
                success, message = False, f"no answer within {args.timeout:g} s"
            node.log_event(event="plan", start_wall=start, end_wall=time.time(), success=success, message=message)
            time.sleep(args.period)
        return 0

    return run_session(node, plan_again_and_again)


if __name__ == "__main__":
    raise SystemExit(main())
