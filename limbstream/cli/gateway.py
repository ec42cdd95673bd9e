"""``limbstream gateway KIND``: bridge devices that cannot speak Zenoh into limbstream.

Each kind of gateway is a module named in :data:`GATEWAYS` that defines
``add_arguments(parser)`` and ``run(args) -> int``, like a command (limbstream.cli); it is
imported only when it runs.
"""
from __future__ import annotations

import argparse
import importlib

GATEWAYS: dict[str, tuple[str, str]] = {
    "serial": ("limbstream.cli.gateway_serial",
               "one device on a serial link (USB CDC, a UART, or the device firmware under QEMU on tcp:HOST:PORT)"),
    "slimevr": ("limbstream.cli.gateway_slimevr", "SlimeVR trackers (UDP, port 6969) as limbstream devices"),
}
"""{kind: (module, help)}."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="gateway", required=True, metavar="KIND")
    for kind, (module, help_text) in GATEWAYS.items():
        importlib.import_module(module).add_arguments(sub.add_parser(kind, help=help_text, description=help_text))


def run(args: argparse.Namespace) -> int:
    return int(importlib.import_module(GATEWAYS[args.gateway][0]).run(args) or 0)
