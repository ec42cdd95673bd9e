"""``limbstream router``: a Zenoh router in Python for one machine (compose uses eclipse/zenoh)."""
from __future__ import annotations

import argparse
import os
import re
import threading

import zenoh

from limbstream import zconfig
from limbstream.cli import zenoh_args
from limbstream.signals import stop_on_signals


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--listen", default=zconfig.DEFAULT_ROUTER,
                        help=f"endpoint(s) to listen on, comma-separated (default {zconfig.DEFAULT_ROUTER})")
    parser.add_argument("--connect", default="", help="other routers to mesh with, comma-separated")
    parser.add_argument("--zenoh-config", default=os.environ.get(zconfig.CONFIG_ENV, ""),
                        help=f"JSON file of extra zenoh settings: TLS, auth, ACL (env {zconfig.CONFIG_ENV})")


def run(args: argparse.Namespace, stop: threading.Event | None = None) -> int:
    """Serve until SIGINT/SIGTERM (or ``stop`` is set)."""
    args.mode = "router"
    settings = zenoh_args.from_args(args)
    stop = stop_on_signals(stop)
    try:
        session = zconfig.open_session(settings)
    except zenoh.ZError as exc:  # e.g. the port is taken: one line, without Zenoh's source locations
        raise SystemExit(f"limbstream router: error: --listen {args.listen}: "
                         f"{re.sub(r' at [^ ]+[.]rs:[0-9]+[.]?', '', str(exc))}") from None
    with session:
        print(f"zenoh router {session.zid()} listening on {', '.join(settings.listen)}", flush=True)
        stop.wait()
    return 0
