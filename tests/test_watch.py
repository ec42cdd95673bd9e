"""``limbstream watch`` tells a user what it waits for: a subject that sends nothing (a typo) is
named with the subjects that do stream, and ``--timeout 0`` waits for the router however long it
takes. Real processes: a router, an emulator and an aggregator on free ports."""
from __future__ import annotations

import subprocess

import pytest
from support.command import Command
from support.stack import stack  # noqa: F401  (fixture)

from limbstream import zconfig
from limbstream.cli.watch import HINT_S

pytestmark = pytest.mark.e2e


def test_watch_of_a_subject_that_sends_nothing_names_those_streaming_and_keeps_waiting(stack):  # noqa: F811
    stack.router()
    stack.emulator(subjects=2)
    stack.aggregator()
    good = Command(["watch", "s02", "--connect", stack.endpoint, "--count", "1"])
    assert good.exit_code(60.0)[0] == 0, good.rest()  # (both subjects stream by now)
    typo = Command(["watch", "s99", "--connect", stack.endpoint])
    said = typo.wait_line("limbstream watch: waiting for live frames of s99")
    hinted = typo.wait_line("limbstream watch: no live frame of s99 for")
    assert typo.seen[-1] == (f"limbstream watch: no live frame of s99 for {HINT_S:g} s; subjects streaming: s01, "
                             "s02; still waiting (Ctrl-C stops)"), typo.seen
    assert HINT_S <= hinted - said <= HINT_S + 3.0, hinted - said
    assert typo.proc.poll() is None, "it keeps waiting"
    typo.interrupt()
    assert typo.exit_code(10.0)[0] == 130 and typo.rest()[-1] == "limbstream watch: stopped", typo.rest()
    # a timeout shorter than a stats round: the subjects streaming come from the aggregator's answer
    with_timeout = Command(["watch", "s99", "--connect", stack.endpoint, "--timeout", "0.2"])
    assert with_timeout.exit_code(30.0)[0] == 1
    assert with_timeout.rest()[-1] == "limbstream watch: no live frame of s99 for 0.2 s; subjects streaming: s01, s02"


def test_watch_with_timeout_0_waits_for_the_router_however_long_it_takes(stack):  # noqa: F811
    """No router for longer than the commands' default connect timeout: watch still waits, and
    shows the frames once a router and the system behind it come."""
    cmd = Command(["watch", "s01", "--timeout", "0", "--connect", stack.endpoint])
    cmd.wait_line(f"connecting to {stack.endpoint} (--connect, env LIMBSTREAM_ROUTER; waiting for it however "
                  "long it takes)")
    with pytest.raises(subprocess.TimeoutExpired):  # what it must not do: give up after the default bound
        cmd.proc.wait(zconfig.CONNECT_TIMEOUT_S + 2.0)
    stack.router()
    stack.emulator(subjects=1)
    stack.aggregator()
    cmd.wait_line("s01  live #", timeout=60)
    cmd.interrupt()
    assert cmd.exit_code(10.0)[0] == 130
    assert "Traceback" not in "\n".join(cmd.rest()), cmd.rest()
