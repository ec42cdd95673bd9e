"""``limbstream`` command line: one subcommand per tool, each in its own module.

This package is the top layer: it starts the parts (``device_emulator``, ``services``) and the
tools built on the core library (``limbstream.wire``, ``kernel``, ``sources``, ...); nothing
below imports it.

Every module named in :data:`COMMANDS` defines ``add_arguments(parser)`` and ``run(args) -> int``.
Modules are imported only when their command runs (nothing opens a session at import time).
"""
from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import signal
import sys
import threading
import warnings

COMMANDS: dict[str, tuple[str, str]] = {
    "up": ("limbstream.cli.up", "run the whole live system on this machine"),
    "router": ("limbstream.cli.router", "run a Zenoh router (for one machine, no plugins)"),
    "emulate": ("limbstream.cli.emulate", "run emulated IMU devices"),
    "aggregate": ("limbstream.cli.aggregate", "run the aggregator (SLERP + fusion)"),
    "gateway": ("limbstream.cli.gateway", "bridge devices that cannot speak Zenoh (SlimeVR trackers, a serial link)"),
    "clock": ("limbstream.cli.clock", "serve the common time base the devices synchronise to"),
    "dashboard": ("limbstream.cli.dashboard", "run the dashboard web service"),
    "calibrate": ("limbstream.cli.calibrate", "calibrate a subject's devices from the pose it holds"),
    "watch": ("limbstream.cli.watch", "print a live text view of a subject's pose stream"),
    "eval": ("limbstream.cli.evaluate", "evaluate segmentation algorithms on motion files"),
    "fuse": ("limbstream.cli.fuse", "the device's orientation per sample for every sensor of a raw recording"),
    "record": ("limbstream.cli.record", "record what crosses the router to an MCAP file"),
    "replay": ("limbstream.cli.replay", "publish a recording's devices again (segment points, truth)"),
    "export": ("limbstream.cli.export", "export a recording or motion file to BVH, CSV or npz"),
    "foxglove": ("limbstream.cli.foxglove", "serve the live pose and stats to the Foxglove app (WebSocket)"),
    "vmc": ("limbstream.cli.vmc", "send a subject's live pose to avatar apps (VMC protocol, OSC/UDP)"),
    "vrchat": ("limbstream.cli.vrchat", "send a subject's live pose to VRChat as OSC trackers (OSC/UDP)"),
}


DESCRIPTION = ("Live full-body motion capture over Zenoh from wearable IMUs that send only fastSW segment "
               "points. `limbstream up` runs the whole live system on this machine; `limbstream COMMAND --help` "
               "lists a command's flags.")


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with one subparser per command."""
    parser = argparse.ArgumentParser(prog="limbstream", description=DESCRIPTION)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (_, help_text) in COMMANDS.items():
        sub.add_parser(name, help=help_text, description=help_text)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``limbstream`` script. A bad flag: one line, exit status 2, before the
    command starts anything. Ctrl-C at any moment: ``limbstream COMMAND: stopped``, exit status 130,
    without a traceback (a command that handles it itself says so and exits its own way)."""
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser()
    if not argv or argv[0] not in COMMANDS:
        parser.parse_args(argv)  # prints usage / error and exits
        return 2
    name = argv[0]
    # Ctrl-C raises KeyboardInterrupt even where SIGINT came ignored (a job a shell started in the
    # background: Python then leaves it ignored, and the command would not stop on it)
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return _run(name, argv[1:])
    except KeyboardInterrupt:
        print(f"limbstream {name}: stopped", file=sys.stderr, flush=True)
        return 130


def console() -> None:
    """The ``limbstream`` script and ``python -m limbstream.cli``: :func:`main`, then the process
    exits at once. The command has closed its sessions, files and children by then; the
    interpreter's teardown, skipped here, would spend 0.3-1 s collecting Zenoh's runtime and the
    native objects, and a command must be gone within half a second of Ctrl-C."""
    code = main()
    if "logging" in sys.modules:
        sys.modules["logging"].shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe (`limbstream ... | head`)
            pass
    os._exit(code)


@contextlib.contextmanager
def notes_as_lines(prog: str):
    """While it lasts, a source's notes (:class:`limbstream.sources.SourceNote`) print as one line
    on stderr, ``PROG: note: ...`` (other warnings as Python shows them)."""
    from limbstream.sources import SourceNote

    with warnings.catch_warnings():
        shown = warnings.showwarning

        def show(message, category, filename, lineno, file=None, line=None):
            if issubclass(category, SourceNote):
                print(f"{prog}: note: {message}", file=sys.stderr, flush=True)
            else:
                shown(message, category, filename, lineno, file, line)

        warnings.showwarning = show
        yield


def _run(name: str, argv: list[str]) -> int:
    from limbstream import zconfig
    from limbstream.cli import flags
    module = importlib.import_module(COMMANDS[name][0])
    sub = argparse.ArgumentParser(prog=f"limbstream {name}", description=COMMANDS[name][1])
    module.add_arguments(sub)
    args = sub.parse_args(argv)
    try:
        with notes_as_lines(f"limbstream {name}"):
            flags.check_shared(args)
            return int(module.run(args) or 0)
    except flags.FlagError as exc:
        return flags.fail(f"limbstream {name}", str(exc))
    except zconfig.ConnectError as exc:
        print(f"limbstream {name}: error: {exc} ({flags.CONNECT_HINT})", file=sys.stderr)
        return 1


if __name__ == "__main__":
    console()
