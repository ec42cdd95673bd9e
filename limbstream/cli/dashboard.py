"""``limbstream dashboard``: the flags of the dashboard web service (the part:
:mod:`limbstream.services.dashboard.main`)."""
from __future__ import annotations

import argparse
import os

from limbstream.cli import flags

from limbstream.services.dashboard import main as dashboard
from limbstream.services.dashboard.settings import DashboardSettings


def parse_http(value: str) -> tuple[str, int]:
    """``HOST:PORT`` (or ``:PORT``, ``[::1]:PORT``) -> (host, port); argparse error otherwise."""
    try:
        return flags.parse_http(value)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    default = f"{os.environ.get('LIMBSTREAM_HOST', '127.0.0.1')}:{os.environ.get('LIMBSTREAM_PORT', '8000')}"
    parser.add_argument("--http", type=parse_http, default=parse_http(default), metavar="HOST:PORT",
                        help=f"where to serve HTTP (default {default}; 0.0.0.0 to expose it)")
    parser.add_argument("--app-mode", choices=("development", "production"), default=None,
                        help="development generates an API token if LIMBSTREAM_API_TOKEN is unset; "
                             "production disables device control instead (env LIMBSTREAM_MODE)")
    parser.add_argument("--cors-origin", action="append", default=None, metavar="ORIGIN",
                        help="allow this extra origin (repeatable; default: same origin only)")
    parser.add_argument("--log-level", default="warning", help="uvicorn log level (default warning)")
    flags.add_zenoh(parser, timeout=False)  # a server: it waits for its router


def settings_from_args(args: argparse.Namespace) -> DashboardSettings:
    """DashboardSettings from the environment (LIMBSTREAM_*), overridden by the flags given."""
    if args.mode == "router":
        raise SystemExit("limbstream dashboard: --mode must be client or peer")
    host, port = args.http
    overrides = {"host": host, "port": port, "router": args.connect, "zenoh_mode": args.mode,
                 "zenoh_config": args.zenoh_config}
    if args.app_mode:
        overrides["mode"] = args.app_mode
    if args.cors_origin:
        overrides["cors_origins"] = args.cors_origin
    return DashboardSettings().model_copy(update=overrides)


def run(args: argparse.Namespace) -> int:
    return dashboard.run(settings_from_args(args), args.log_level)
