"""One command line run as a user runs it, its output (stdout and stderr) read line by line as it
comes, so that a test waits on the line that marks an event (``connecting``, a banner), not on time."""
from __future__ import annotations

import os
import queue
import signal
import subprocess
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

from limbstream.launch import LIMBSTREAM
from support import ROOT


def _sigint_as_a_terminal_has_it() -> None:
    """In the child before exec: SIGINT at its default, whatever this process had (a run started
    as a shell's background job has it ignored, and a child inherits that: pytest, make and
    other non-limbstream commands a test interrupts would then go on)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


class Command:
    """``argv`` (a ``limbstream`` command's arguments, or with ``shell`` a line for ``sh -c``,
    ``prefix`` before it, e.g. ``ip netns exec NS``) started in ``cwd`` in a process group of its
    own; ``env``: its whole environment (None: this process's)."""

    def __init__(self, argv: Sequence[str] | str, cwd: Path = ROOT, env: Mapping[str, str] | None = None,
                 shell: bool = False, prefix: Sequence[str] = ()):
        command = ["sh", "-c", f"exec {argv}"] if shell else [*LIMBSTREAM, *argv]
        self.proc = subprocess.Popen([*prefix, *command], cwd=cwd, stdin=subprocess.DEVNULL,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                     env=None if env is None else dict(env), start_new_session=True,
                                     preexec_fn=_sigint_as_a_terminal_has_it)
        self.lines: queue.Queue[str] = queue.Queue()
        self.seen: list[str] = []
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.put(line.rstrip("\n"))

    def wait_line(self, text: str, timeout: float = 60.0) -> float:
        """The time the first line containing ``text`` arrived (AssertionError if none came)."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                line = self.lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                code = self.proc.poll()
                raise AssertionError(f"no line with {text!r} within {timeout:g} s (exit {code}): "
                                     + "\n".join(self.seen[-60:])) from None
            self.seen.append(line)
            if text in line:
                return time.monotonic()

    def interrupt(self, group: bool = False) -> float:
        """SIGINT to the command, or with ``group`` to its process group (as Ctrl-C in a terminal
        reaches ``make`` and the command it runs); the time it was sent."""
        if group:
            os.killpg(self.proc.pid, signal.SIGINT)
        else:
            self.proc.send_signal(signal.SIGINT)
        return time.monotonic()

    def exit_code(self, within: float) -> tuple[int, float]:
        """(exit code, time of the exit), waiting at most ``within`` seconds."""
        try:
            code = self.proc.wait(within)
        except subprocess.TimeoutExpired:
            self.kill()
            raise AssertionError(f"still running {within:g} s later: {self.rest()}") from None
        return code, time.monotonic()

    def kill(self) -> None:
        """SIGKILL to its whole process group (what is left of it)."""
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.proc.wait()

    def rest(self) -> list[str]:
        """Every line read so far; once the process has exited, every line it wrote (its output is
        read to the end first: the last lines may still be on their way when it exits)."""
        if self.proc.poll() is not None:
            self.reader.join(10.0)
        while not self.lines.empty():
            self.seen.append(self.lines.get())
        return self.seen
