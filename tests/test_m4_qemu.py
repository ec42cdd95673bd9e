"""The Cortex-M4 build of the kernels under QEMU (mps2-an386) computes the host's segment points.

The firmware (firmware_c/m4/main.c) streams test vectors through fastSW and SW and prints
each segment point's index, tick and float bits (and fastSW's rate, with the live rule on or
off); the host library streams the same vectors through the same C source (ctypes) and must
print the same, bit for bit.
"""
from __future__ import annotations

import ast
import ctypes
import re
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from limbstream import kernel
from support import ROOT
from support.firmware import FIRMWARE, load_tool, make_m4, require_tools

pytestmark = pytest.mark.qemu

TOOLS = ("arm-none-eabi-gcc", "arm-none-eabi-objdump", "qemu-system-arm", "make")
FUSED = re.compile(r"\bv(fma|fms|fnma|fnms)\.f32\b")


vectors = load_tool("vectors")


@pytest.fixture(scope="module")
def build_dir(tmp_path_factory) -> Path:
    """A fresh `make m4` into a temporary build folder."""
    require_tools(*TOOLS)
    return make_m4(tmp_path_factory, "m4build")


def run_qemu(elf: Path, vector_file: Path | None = None, timeout: float = 60.0) -> list[str]:
    """Run a harness ELF under QEMU; return its console lines (semihosting output)."""
    config = "enable=on,target=native"
    if vector_file is not None:
        config += f",arg={elf.name},arg={vector_file}"
    done = subprocess.run(
        ["qemu-system-arm", "-M", "mps2-an386", "-nographic", "-monitor", "none", "-serial", "none",
         "-semihosting-config", config, "-kernel", str(elf)],
        capture_output=True, text=True, timeout=timeout,
    )
    lines = (done.stderr + done.stdout).splitlines()
    assert done.returncode == 0, f"{elf.name} exited with {done.returncode}: {lines[-5:]}"
    return lines


def parse_points(lines: list[str]) -> dict[tuple[str, int], list[tuple[int, ...]]]:
    """Console lines -> {(algorithm, case): [(index, tick, y bits..., [rate bits...]), ...]
    + [(rejected,)]}."""
    result: dict[tuple[str, int], list[tuple[int, ...]]] = {}
    for line in lines:
        parts = line.split()
        if parts and parts[0] == "P":
            result.setdefault((parts[1], int(parts[2])), []).append(
                (int(parts[3]), int(parts[4]), *(int(h, 16) for h in parts[5:])))
        elif parts and parts[0] == "R":
            result.setdefault((parts[1], int(parts[2])), []).append((int(parts[3]),))
    return result


class HostKernels:
    """The host library's streaming fastSW and SW through ctypes (same C source, host compiler)."""

    def __init__(self):
        lib = ctypes.CDLL(kernel._lib._name)  # own handle: own argtypes
        point_p = ctypes.POINTER(kernel.Point)
        f32p = np.ctypeslib.ndpointer(np.float32, flags="C_CONTIGUOUS")
        for prefix in ("fastsw", "sw"):
            getattr(lib, f"{prefix}_init").argtypes = [ctypes.c_void_p, ctypes.POINTER(kernel.Settings)]
            getattr(lib, f"{prefix}_update").argtypes = [ctypes.c_void_p, ctypes.c_uint32, f32p, point_p]
            getattr(lib, f"{prefix}_flush").argtypes = [ctypes.c_void_p, point_p]
        lib.fastsw_point_rate.argtypes = [ctypes.c_void_p, f32p]
        self.lib = lib
        self.state = ctypes.create_string_buffer(max(kernel.STATE_SIZE, kernel.SW_STATE_SIZE))

    def points(self, algorithm: str, case) -> list[tuple[int, ...]]:
        """Segment points (index, tick, y bits[, rate bits]) and finally (rejected,) of one case."""
        lib, point = self.lib, kernel.Point()
        settings = kernel.Settings(case.threshold, case.max_len, 4, case.live_bound_deg)
        assert getattr(lib, f"{algorithm}_init")(self.state, ctypes.byref(settings)) == 0
        update = getattr(lib, f"{algorithm}_update")
        out, rejected = [], 0
        rate = np.zeros(4, np.float32)

        def emit():
            y = np.array(point.y[:4], np.float32).view(np.uint32)
            if algorithm == "fastsw":
                lib.fastsw_point_rate(self.state, rate)
                y = np.concatenate([y, rate.view(np.uint32)])
            out.append((point.index, point.t, *map(int, y)))

        for tick, y in zip(case.ticks, np.ascontiguousarray(case.y, np.float32)):
            status = update(self.state, int(tick), y, ctypes.byref(point))
            if status == kernel.POINT:
                emit()
            rejected += status == kernel.REJECTED
        if getattr(lib, f"{algorithm}_flush")(self.state, ctypes.byref(point)) == kernel.POINT:
            emit()
        return out + [(rejected,)]


def host_points(cases) -> dict[tuple[str, int], list[tuple[int, ...]]]:
    host = HostKernels()
    return {(alg, k): host.points(alg, case) for k, case in enumerate(cases) for alg in ("fastsw", "sw")}


def assert_same(m4: dict, host: dict) -> None:
    assert set(m4) == set(host), f"cases differ: {sorted(set(m4) ^ set(host))[:5]}"
    for key in sorted(host):
        assert m4[key] == host[key], (
            f"{key}: M4 and host differ; first differing point: "
            f"{next((a, b) for a, b in zip(m4[key] + [None] * 9, host[key]) if a != b)}"
        )


def test_default_vectors_bit_identical(build_dir):
    lines = run_qemu(build_dir / "m4.elf")
    cases = vectors.synthetic_cases()
    assert lines[-1] == f"done {len(cases)}", lines[-3:]
    m4 = parse_points(lines)
    assert_same(m4, host_points(cases))
    # the vectors exercise what they claim: breaks, rejections, a point per sample at threshold 0,
    # the live rule's points (nonzero rates, some known from their own sample) where it is on
    fastsw = {k: m4[("fastsw", k)] for k in range(len(cases))}
    assert all(len(p) - 1 >= 4 for p in fastsw.values()), {k: len(p) for k, p in fastsw.items()}
    assert fastsw[5][-1][0] == 4, f"NaN, Inf and 2 time faults expected rejected, got {fastsw[5][-1]}"
    assert fastsw[12][-1][0] == 4, f"live rule: faults expected rejected, got {fastsw[12][-1]}"
    assert len(fastsw[6]) - 1 == len(cases[6].ticks), "threshold 0: every sample a point"
    for k, case in enumerate(cases):
        rated = sum(any(p[6:10]) for p in fastsw[k][:-1])
        assert (rated > 2) == (case.live_bound_deg > 0), (k, rated)
    host = HostKernels()
    plain = {k: host.points("fastsw", vectors.Case(c.threshold, c.max_len, c.ticks, c.y)) for k, c in enumerate(cases)}
    assert [p[0] for p in fastsw[7]] != [p[0] for p in plain[7]], "the live rule adds points"


def test_real_motion_bit_identical(build_dir, cmu_npz, tmp_path):
    cases = vectors.npz_cases(cmu_npz, count=400)
    blob = tmp_path / "cmu.bin"
    blob.write_bytes(vectors.pack(cases))
    lines = run_qemu(build_dir / "m4.elf", blob)
    assert lines[-1] == f"done {len(cases)}", lines[-3:]
    m4 = parse_points(lines)
    assert_same(m4, host_points(cases))
    n_points = sum(len(p) - 1 for (alg, _), p in m4.items() if alg == "fastsw")
    assert n_points > 10 * len(cases), f"only {n_points} points in {len(cases)} cases"
    live = [k for k, case in enumerate(cases) if case.live_bound_deg > 0]
    assert len(live) == len(cases) // 3 and all(any(any(p[6:10]) for p in m4[("fastsw", k)][:-1]) for k in live)


def test_bad_vector_file_is_an_error(build_dir, tmp_path):
    bad = tmp_path / "bad.bin"
    bad.write_bytes(b"XXXX" + struct.pack("<I", 1))
    done = subprocess.run(
        ["qemu-system-arm", "-M", "mps2-an386", "-nographic", "-monitor", "none", "-serial", "none",
         "-semihosting-config", f"enable=on,target=native,arg=m4.elf,arg={bad}",
         "-kernel", str(build_dir / "m4.elf")],
        capture_output=True, text=True, timeout=60,
    )
    assert done.returncode == 1, f"exit status {done.returncode}"
    assert "not a vector file" in done.stderr


def test_no_fma_contraction_in_either_build(build_dir, tmp_path):
    """Both builds compile the kernels with -ffp-contract=off; with contraction on, the M4
    compiler would fuse multiply-adds (one rounding instead of two) and change results. The only
    fused multiply-adds in the images are the ones float-float asks for, which are exact."""
    setup = ast.parse((ROOT / "setup.py").read_text())
    host_flags = next(ast.literal_eval(node.value) for node in ast.walk(setup)
                      if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "KERNEL_CFLAGS")
    m4_flags = subprocess.run(["make", "-s", "-C", str(FIRMWARE), "print-m4-cflags", f"PYTHON={sys.executable}"],
                              capture_output=True, text=True, check=True).stdout.split()
    assert "-ffp-contract=off" in host_flags, host_flags
    assert "-ffp-contract=off" in m4_flags, m4_flags
    host_vqf = next(ast.literal_eval(node.value) for node in ast.walk(setup)
                    if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "VQF_CXXFLAGS")
    m4_vqf = subprocess.run(["make", "-s", "-C", str(FIRMWARE), "print-vqf-cxxflags", f"PYTHON={sys.executable}"],
                            capture_output=True, text=True, check=True).stdout.split()
    assert "-ffp-contract=off" in host_vqf and "-ffp-contract=off" in m4_vqf, (host_vqf, m4_vqf)
    assert "-DVQF_SINGLE_PRECISION" in m4_vqf and "VQF_SINGLE_PRECISION" in (ROOT / "setup.py").read_text()

    # the images, and the raw-sample pipeline's objects (VQF's C++ and its elementary functions,
    # src/lsw_math.hpp, among them; the device image links no libm)
    def fused_in(binary) -> int:
        return len(FUSED.findall(subprocess.run(["arm-none-eabi-objdump", "-d", str(binary)],
                                                capture_output=True, text=True, check=True).stdout))

    for binary in ("m4.elf", "icount.elf", "lsw_imu.o", "device.o"):
        assert not fused_in(build_dir / binary), f"fused multiply-add in the -ffp-contract=off build ({binary})"
    # VQF's single precision asks for one on purpose: the exact error of a float-float product
    # (src/lsw_ff.hpp, two_prod_err); built without it, VQF holds none, so every one in the image is that
    asked = fused_in(build_dir / "lsw_vqf.o")
    assert 0 < fused_in(build_dir / "device.elf") <= asked
    without = tmp_path / "lsw_vqf_no_fma.o"
    subprocess.run(["arm-none-eabi-g++", *m4_vqf, "-DLSW_FF_NO_FMA", "-c", str(FIRMWARE / "src" / "lsw_vqf.cpp"), "-o",
                    str(without)], check=True, cwd=FIRMWARE)
    assert fused_in(without) == 0, "fused multiply-add in VQF beyond float-float's product error"

    contracted = tmp_path / "fastsw_fma.o"
    flags = [f if f != "-ffp-contract=off" else "-ffp-contract=fast" for f in m4_flags]
    subprocess.run(["arm-none-eabi-gcc", *flags, "-I", str(FIRMWARE / "include"), "-c",
                    str(FIRMWARE / "src" / "fastsw.c"), "-o", str(contracted)], check=True, cwd=FIRMWARE)
    fused = FUSED.findall(subprocess.run(["arm-none-eabi-objdump", "-d", str(contracted)],
                                         capture_output=True, text=True, check=True).stdout)
    assert len(fused) >= 4, f"expected fused multiply-adds with -ffp-contract=fast, found {fused}"
