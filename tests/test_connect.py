"""No command waits silently for a router that is not there: each says where it connects, gives
up with an error naming the endpoint and how to set it within its timeout (+ 2 s), and every
client command stops within half a second of Ctrl-C (SIGINT), whatever it waits on: a router that
does not answer, or data that does not come. Real processes; the endpoint is a port nothing
listens on, or a real router with nothing behind it."""
from __future__ import annotations


import pytest
from support.command import Command
from support.stack import PAPER10, free_port, stack  # noqa: F401  (fixture)

from limbstream import wire
from limbstream.services.outputs.recording import RecordingWriter

pytestmark = pytest.mark.e2e

TIMEOUT_S = 1.0
COMMANDS = {
    "watch": ["watch", "s01", "--timeout", f"{TIMEOUT_S:g}"],
    "calibrate": ["calibrate", "s01", "--pose", "rest", "--connect-timeout", f"{TIMEOUT_S:g}"],
    "record": ["record", "{tmp}/session.mcap", "--duration", "5", "--connect-timeout", f"{TIMEOUT_S:g}"],
    "emulate": ["emulate", "--subjects", "1", "--connect-timeout", f"{TIMEOUT_S:g}"],
    "aggregate": ["aggregate", "--connect-timeout", f"{TIMEOUT_S:g}"],
}
"""Commands of each kind: a viewer with its own --timeout, a one-shot query, an output that writes a
file, a part that `limbstream up` supervises (which waits: --connect-timeout 0), a service."""
STOP_S = 0.5
"""A client command exits within this many seconds of Ctrl-C, whatever it waits on."""
CLIENTS = {
    "watch": (["watch", "s01"], "waiting for live frames of s01"),
    "calibrate": (["calibrate", "s01", "--pose", "rest", "--countdown", "60"], "hold the rest pose in 60"),
    "record": (["record", "{tmp}/session.mcap"], "recording subjects"),
    "foxglove": (["foxglove", "--port", "0"], "connected; waiting for the pose and stats"),
    "vmc": (["vmc", "--subject", "s01", "--to", "127.0.0.1:{port}"], "s01 -> 127.0.0.1"),
    "vrchat": (["vrchat", "--subject", "s01", "--to", "127.0.0.1:{port}"], "s01 -> 127.0.0.1"),
    "replay": (["replay", "{tmp}/take.mcap"], "replaying"),
    "aggregate": (["aggregate"], "aggregating subjects"),
    "emulate": (["emulate", "--subjects", "1", *PAPER10], "emulating 10 devices"),
    "clock": (["clock"], "serving time on"),
    "gateway slimevr": (["gateway", "slimevr", "--udp", "127.0.0.1:0"], "slimevr gateway slimevr on udp"),
    "gateway serial": (["gateway", "serial", "--port", "tcp:127.0.0.1:{port}", "--subject", "s01", "--segment", "hip"],
                       "opening the link"),
}
"""Every command that connects to a router as a client, with its default wait for the router, and
the line it prints once connected, waiting for data (or for its device, the serial gateway)."""


def take(path) -> None:
    """A recording whose one device's points span a minute: a replay of it waits between them."""
    writer = RecordingWriter(path, skeleton=False)
    key, t0 = wire.seg_key("s01", "hip"), 1_800_000_000_000_000
    for seq in range(3):
        point = wire.SegmentPoint(7, seq, 10 * seq, t0 + 30_000_000 * seq, (1.0, 0.0, 0.0, 0.0))
        writer.add("seg", key, wire.encode_point(point), 30_000_000_000 * seq)
    writer.close()


@pytest.mark.parametrize("name", list(COMMANDS))
def test_without_a_router_a_command_says_where_and_gives_up_in_time(name, tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cmd = Command([a.format(tmp=tmp_path) for a in COMMANDS[name]] + ["--connect", endpoint])
    said = cmd.wait_line(f"connecting to {endpoint} (--connect, env LIMBSTREAM_ROUTER; up to {TIMEOUT_S:g} s)")
    code, ended = cmd.exit_code(TIMEOUT_S + 2.0)
    lines = cmd.rest()
    print(f"\nCONNECT | {name} | gave up {ended - said:.2f} s after saying where (timeout {TIMEOUT_S:g} s) |")
    assert code == 1 and ended - said <= TIMEOUT_S + 2.0, (code, ended - said, lines)
    assert lines[-1] == (f"limbstream {name}: error: no Zenoh router answered at {endpoint} within {TIMEOUT_S:g} s "
                         "(set the router's endpoint with --connect or LIMBSTREAM_ROUTER; `limbstream up` or "
                         "`limbstream router` starts one)"), lines
    assert not list(tmp_path.iterdir()), "no file is left behind"


@pytest.mark.parametrize("router", [False, True], ids=["no router", "router without data"])
@pytest.mark.parametrize("name", list(CLIENTS))
def test_ctrl_c_stops_every_client_within_half_a_second(name, router, stack, tmp_path):  # noqa: F811
    """Started with no router (waiting for it: its default timeout is far off) or behind a router
    with nothing else (waiting for data): SIGINT once the command says so; it exits within
    STOP_S of the signal, without a traceback, and without a router leaves no file behind."""
    files = tmp_path / "files"  # (the router's log goes to tmp_path)
    files.mkdir()
    take(files / "take.mcap")
    argv, ready = CLIENTS[name]
    if router:
        stack.router()
    endpoint = stack.endpoint if router else f"tcp/127.0.0.1:{free_port()}"
    cmd = Command([a.format(tmp=files, port=free_port()) for a in argv] + ["--connect", endpoint])
    cmd.wait_line(ready if router else f"connecting to {endpoint}")
    sent = cmd.interrupt()
    code, ended = cmd.exit_code(10.0)
    print(f"\nCONNECT | {name} | {'router, no data' if router else 'no router'} | stopped {ended - sent:.2f} s "
          "after SIGINT |")
    assert code in (0, 130) and "Traceback" not in "\n".join(cmd.rest()), (code, cmd.rest())
    assert ended - sent <= STOP_S, (ended - sent, cmd.rest())
    if not router:  # (behind a router, record has written what came: nothing)
        assert [p.name for p in files.iterdir()] == ["take.mcap"], "no file is left behind"


def test_the_dashboard_says_it_still_waits_for_its_router_and_stops_on_ctrl_c():
    """The dashboard, a server, keeps waiting for its router (/health 503 meanwhile), but says so
    once the default connect timeout has passed; Ctrl-C stops it within STOP_S."""
    from limbstream import zconfig
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cmd = Command(["dashboard", "--http", f"127.0.0.1:{free_port()}", "--connect", endpoint])
    cmd.wait_line(f"(zenoh client -> {endpoint})")
    cmd.wait_line(f"dashboard: no Zenoh router answered at {endpoint} within {zconfig.CONNECT_TIMEOUT_S:g} s; "
                  "still waiting", timeout=zconfig.CONNECT_TIMEOUT_S + 10)
    sent = cmd.interrupt()
    code, ended = cmd.exit_code(10.0)
    assert ended - sent <= STOP_S and code in (0, 130), (ended - sent, code, cmd.rest())
    assert "Traceback" not in "\n".join(cmd.rest()), cmd.rest()


def test_ctrl_c_stops_a_command_that_came_with_sigint_ignored():
    """A command a shell started in the background inherits SIGINT ignored (Python then leaves it
    so): it still stops on SIGINT, within STOP_S, saying so."""
    import shlex

    from limbstream.launch import LIMBSTREAM
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    watch = shlex.join([*LIMBSTREAM, "watch", "s01", "--connect", endpoint])
    cmd = Command(f"sh -c {shlex.quote(f'trap {chr(39) * 2} INT; exec {watch}')}", shell=True)
    cmd.wait_line(f"connecting to {endpoint}")
    sent = cmd.interrupt()
    code, ended = cmd.exit_code(10.0)
    assert code == 130 and ended - sent <= STOP_S, (code, ended - sent, cmd.rest())
    assert cmd.rest()[-1] == "limbstream watch: stopped", cmd.rest()
