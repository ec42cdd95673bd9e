"""The Zenoh flags every command that opens a session shares (``--connect``, ``--listen``,
``--mode``, ``--zenoh-config``, ``--connect-timeout``), and the line that says where it connects.

The settings themselves are :class:`limbstream.zconfig.ZenohSettings`.
"""
from __future__ import annotations

import argparse
import os
import sys

from limbstream import zconfig

HINT = (f"set the router's endpoint with --connect or {zconfig.ROUTER_ENV}; `limbstream up` or "
        "`limbstream router` starts one")
"""What a user can do when no router answers (printed after :class:`zconfig.ConnectError`)."""


def add_arguments(parser: argparse.ArgumentParser, mode: str = "client", timeout: bool = True) -> None:
    """The shared Zenoh flags (router default from $LIMBSTREAM_ROUTER); without ``timeout``, the
    command bounds the wait for its router with a flag of its own (``watch --timeout``)."""
    group = parser.add_argument_group("zenoh")
    default = os.environ.get(zconfig.ROUTER_ENV, zconfig.DEFAULT_ROUTER if mode != "router" else "")
    group.add_argument("--connect", default=default, metavar="ENDPOINT[,ENDPOINT...]",
                       help=f"router endpoint(s) to connect to (env {zconfig.ROUTER_ENV}; default {default or 'none'})")
    group.add_argument("--listen", default="", metavar="ENDPOINT[,ENDPOINT...]", help="endpoint(s) to listen on")
    group.add_argument("--mode", default=mode, choices=("client", "peer", "router"), help=f"zenoh mode (default {mode})")
    group.add_argument("--zenoh-config", default=os.environ.get(zconfig.CONFIG_ENV, ""), metavar="FILE",
                       help=f"JSON file of extra zenoh settings (key -> value), e.g. TLS/auth (env {zconfig.CONFIG_ENV})")
    if timeout:
        group.add_argument("--connect-timeout", type=float, default=zconfig.CONNECT_TIMEOUT_S, metavar="S",
                           help=f"give up when no router answers within S seconds (default "
                                f"{zconfig.CONNECT_TIMEOUT_S:g}; 0: wait however long it takes)")


def from_args(args: argparse.Namespace, connect_timeout_s: float | None = None) -> zconfig.ZenohSettings:
    """ZenohSettings from the flags of :func:`add_arguments`; ``connect_timeout_s`` stands in for
    ``--connect-timeout`` where the command has no such flag (None or 0: wait). SystemExit naming
    a bad ``--zenoh-config`` or ``--connect-timeout``."""
    extra = {}
    if args.zenoh_config:
        try:
            extra = zconfig.read_extra(args.zenoh_config)
        except ValueError as exc:
            raise SystemExit(f"--zenoh-config {exc}") from None
    timeout = getattr(args, "connect_timeout", connect_timeout_s)
    if timeout is not None and not timeout >= 0:
        raise SystemExit(f"--connect-timeout must be >= 0, got {timeout:g}")
    return zconfig.ZenohSettings(mode=args.mode, connect=zconfig.split_list(args.connect),
                                 listen=zconfig.split_list(args.listen), extra=extra,
                                 connect_timeout_s=timeout or None)


def announce(prog: str, settings: zconfig.ZenohSettings) -> None:
    """One line on stderr: where ``prog`` connects, how to change it, and how long it waits."""
    if settings.mode == "router" or not settings.connect:
        return
    wait = ("waiting for it however long it takes" if settings.connect_timeout_s is None
            else f"up to {settings.connect_timeout_s:g} s")
    print(f"{prog}: connecting to {', '.join(settings.connect)} (--connect, env {zconfig.ROUTER_ENV}; {wait})",
          file=sys.stderr, flush=True)


def session_settings(args: argparse.Namespace, prog: str, connect_timeout_s: float | None = None
                     ) -> zconfig.ZenohSettings:
    """:func:`from_args`, announced (:func:`announce`): what a command calls right before it
    opens its session."""
    settings = from_args(args, connect_timeout_s)
    announce(prog, settings)
    return settings
