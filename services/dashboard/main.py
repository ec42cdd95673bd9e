"""``limbstream dashboard``: run the dashboard web service with uvicorn."""
from __future__ import annotations

import argparse
import os

from limbstream import zconfig

from .settings import DashboardSettings


def parse_http(value: str) -> tuple[str, int]:
    """``HOST:PORT`` (or ``:PORT``, ``[::1]:PORT``) -> (host, port); argparse error otherwise."""
    host, sep, port = value.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"--http expects HOST:PORT, got {value!r}")
    return (host.strip("[]") or "127.0.0.1"), int(port)


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
    zconfig.add_arguments(parser)


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from .app import create_app

    host, port = args.http
    overrides = {"host": host, "port": port, "router": args.connect, "zenoh_mode": args.mode,
                 "zenoh_config": args.zenoh_config}
    if args.mode == "router":
        raise SystemExit("limbstream dashboard: --mode must be client or peer")
    if args.app_mode:
        overrides["mode"] = args.app_mode
    if args.cors_origin:
        overrides["cors_origins"] = args.cors_origin
    settings = DashboardSettings().model_copy(update=overrides)
    settings, generated = settings.with_token()
    config = uvicorn.Config(create_app(settings), host=host, port=port, log_level=args.log_level,
                            ws_ping_interval=20, timeout_graceful_shutdown=3)
    server = uvicorn.Server(config)
    shown = "[::1]" if host == "::1" else ("127.0.0.1" if host in ("0.0.0.0", "") else host)
    print(f"dashboard: http://{shown}:{port}/ (zenoh {settings.zenoh_mode} -> {settings.router})", flush=True)
    if generated:
        print(f"dashboard: development API token (set LIMBSTREAM_API_TOKEN to choose one): "
              f"{settings.api_token.get_secret_value()}", flush=True)
    elif settings.api_token is None:
        print("dashboard: device control disabled (production mode and no LIMBSTREAM_API_TOKEN)", flush=True)
    server.run()
    return 0
