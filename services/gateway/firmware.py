"""The device firmware (firmware_c/m4/device_main.c) run under QEMU ``mps2-an386``, its UART0
on a TCP socket that QEMU serves on 127.0.0.1 (a serial link: ``tcp:127.0.0.1:PORT``), or on a
pseudo-terminal (a tty, as a USB or UART device appears: ``/dev/pts/N``)."""
from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

from limbstream.launch import _die_with_parent, free_port

ROOT = Path(__file__).resolve().parent.parent.parent
FIRMWARE_DIR = ROOT / "firmware_c"
DEFAULT_ELF = FIRMWARE_DIR / "build" / "device.elf"
QEMU = "qemu-system-arm"


def build(build_dir: Path | None = None, vqf_precision: str | None = None) -> Path:
    """``make device`` (into firmware_c/build, firmware_c/build-single for VQF in single precision,
    or ``build_dir``) in the source checkout this package runs from (an installed wheel carries no
    firmware source: give an ELF instead), with VQF in ``vqf_precision`` (``"single"`` or
    ``"double"``; default the firmware's); the ELF's path. RuntimeError with make's output if the
    build fails."""
    from limbstream.kernel import fusion
    vqf_precision = vqf_precision or fusion.DEFAULT_VQF_PRECISION
    if build_dir is None and vqf_precision != fusion.DEFAULT_VQF_PRECISION:
        build_dir = FIRMWARE_DIR / f"build-{vqf_precision}"
    if not (FIRMWARE_DIR / "Makefile").exists():
        raise RuntimeError(f"no firmware source at {FIRMWARE_DIR}: build device.elf from a checkout and give its path")
    args = ["make", "-s", "-C", str(FIRMWARE_DIR), "device", f"PYTHON={sys.executable}",  # it has vqf's C++
            f"VQF_PRECISION={vqf_precision}"]
    args += [f"BUILD={build_dir}"] if build_dir else []
    done = subprocess.run(args, capture_output=True, text=True, timeout=300)
    if done.returncode != 0:
        raise RuntimeError(f"make device failed:\n{done.stdout}\n{done.stderr}")
    return (build_dir / "device.elf") if build_dir else DEFAULT_ELF


def qemu_command(elf: Path, port: int | None) -> list[str]:
    """QEMU running ``elf`` with UART0 served on 127.0.0.1:``port`` (the host connects after
    QEMU listens), or with ``port`` None on a pseudo-terminal (QEMU prints its path);
    semihosting lets a fault end the run (exit status 99)."""
    chardev = "pty,id=u0" if port is None else f"socket,id=u0,host=127.0.0.1,port={port},server=on,wait=off"
    return [QEMU, "-M", "mps2-an386", "-nographic", "-monitor", "none",
            "-semihosting-config", "enable=on,target=native", "-kernel", str(elf),
            "-chardev", chardev, "-serial", "chardev:u0"]


class FirmwareDevice:
    """One QEMU process running the device firmware; :attr:`port` is its link
    (``tcp:127.0.0.1:N``, or with ``tty`` a pseudo-terminal's path). Stop it with :meth:`stop`
    (or use it as a context manager)."""

    def __init__(self, elf: Path = DEFAULT_ELF, tty: bool = False):
        if shutil.which(QEMU) is None:
            raise RuntimeError(f"{QEMU} not found (apt install qemu-system-arm)")
        if not Path(elf).exists():
            raise RuntimeError(f"device firmware {elf} not built (make -C firmware_c device)")
        self.tcp_port = None if tty else free_port()
        self.process = subprocess.Popen(qemu_command(Path(elf), self.tcp_port), stdin=subprocess.DEVNULL,
                                        stdout=subprocess.PIPE if tty else subprocess.DEVNULL,
                                        stderr=subprocess.DEVNULL, text=True,
                                        preexec_fn=_die_with_parent())  # no QEMU outlives its device's owner
        if tty:  # "char device redirected to /dev/pts/N (label u0)", before the machine runs
            line = self.process.stdout.readline() if self.process.stdout is not None else ""
            match = re.search(r"(/dev/\S+)", line)
            if match is None:
                self.stop()
                raise RuntimeError(f"QEMU gave no pseudo-terminal: {line!r}")
            self.port = match.group(1)
        else:
            self.port = f"tcp:127.0.0.1:{self.tcp_port}"

    def alive(self) -> bool:
        return self.process.poll() is None

    def stop(self) -> None:
        if self.process.stdout is not None:
            self.process.stdout.close()
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()

    def __enter__(self) -> FirmwareDevice:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
