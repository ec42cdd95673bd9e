"""Exact instructions executed per call of fastsw_update and sw_update on the Cortex-M4.

Runs ``build/icount.elf`` (firmware_c/m4/icount_main.c) under QEMU ``mps2-an386`` with one
guest instruction per translation block (``-singlestep``, or ``-accel tcg,one-insn-per-tb=on``
on QEMU >= 8.1) and ``-d exec,nochain``, so the log has one line per executed instruction.
``-dfilter`` keeps only the measured functions, everything they call, and the return
addresses of their call sites: a call's count is the number of lines from the function's
entry up to (not including) the return address (a measured function called inside another is
counted in both). The harness announces each call on the
semihosting console ("F ssr_break", "S 17", ...), in call order, which labels the counts.
A naked function of known length (icount_probe: 3 + 3k instructions) checks the counting.

Usage::

    python3 icount.py build/icount.elf [--json]

prints the tables, ``fastsw max instructions per sample: N`` (live rule off) and
``fastsw live max instructions per sample: N`` (live rule on, every branch). With ``--device``
it traces ``build/icount_device.elf`` (m4/icount_device_main.c) instead: the device firmware's
whole work per sample, link decode to framed point, ``device max instructions per sample: N``.
With ``--imu`` it traces ``build/icount_imu.elf`` (m4/icount_imu_main.c): VQF per raw sample (6D,
9D) and the raw-sample pipeline per raw and per device sample, ``vqf 6d max instructions per raw
sample: N`` and ``imu max instructions per device sample: N``.
"""
from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np

MEASURED = {"icount_probe": "K", "fastsw_update": "F", "sw_update": "S"}
"""Function -> the letter its calls are announced with."""
DEVICE_MEASURED = {"icount_device_frame": "D"}
"""The same for the device harness."""
IMU_MEASURED = {"icount_imu": "P", "lsw_vqf_gyr": "G", "lsw_vqf_acc": "A"}
"""The same for the raw-sample pipeline's harness; VQF's two updates (6D) are counted inside it and
are not announced."""

FASTSW_BRANCHES = ("first", "normal", "ssr_break", "max_len_break", "reject_nan", "reject_time")
LIVE_BRANCHES = ("live_first", "live_normal", "live_close", "live_ssr_break", "live_max_len_break",
                 "live_reject_nan", "live_reject_time")
"""Branches with the live rule on: the plain ones and a live close (the sample becomes a point)."""
TRACE_LINE = re.compile(r"^Trace \d+: 0x[0-9a-f]+ \[[0-9a-f]+/([0-9a-f]+)/")
CALL_LINE = re.compile(r"^\s*([0-9a-f]+):\s+(?:[0-9a-f]{4}(?: [0-9a-f]{4})?\s+)?(bl|b\.w|b)\s+[0-9a-f]+ <([^>+]+)>")


def _tool(name: str) -> str:
    path = shutil.which(name)
    if path is None:
        raise FileNotFoundError(f"{name} not found on PATH (apt install gcc-arm-none-eabi qemu-system-arm)")
    return path


def symbols(elf: Path) -> dict[str, tuple[int, int]]:
    """Function symbols of the ELF: name -> (address, size in bytes), Thumb bit cleared."""
    out = subprocess.run([_tool("arm-none-eabi-nm"), "-S", str(elf)], capture_output=True, text=True, check=True)
    table = {}
    for line in out.stdout.splitlines():
        parts = line.split()
        if len(parts) == 4 and parts[2] in "TtWw":  # W: libgcc's soft-float aliases (__aeabi_dmul)
            table[parts[3]] = (int(parts[0], 16) & ~1, int(parts[1], 16))
    return table


def call_graph(elf: Path, syms: dict[str, tuple[int, int]]) -> tuple[dict[str, set[str]], dict[str, set[int]]]:
    """From the disassembly: callees of each function (bl and tail-call branches to other
    functions) and, per function, the return addresses of its bl call sites."""
    out = subprocess.run(
        [_tool("arm-none-eabi-objdump"), "-d", str(elf)], capture_output=True, text=True, check=True
    ).stdout
    callees: dict[str, set[str]] = defaultdict(set)
    returns: dict[str, set[int]] = defaultdict(set)
    current = None
    lines = out.splitlines()
    for line in lines:
        head = re.match(r"^[0-9a-f]+ <([^>]+)>:", line)
        if head:
            current = head.group(1)
            continue
        match = CALL_LINE.match(line)
        if not match or current is None:
            continue
        address, op, target = int(match.group(1), 16), match.group(2), match.group(3)
        if target != current and target in syms:
            callees[current].add(target)
            if op == "bl":
                returns[target].add(address + 4)  # bl is a 32-bit instruction
    return callees, returns


def reachable(roots: list[str], callees: dict[str, set[str]]) -> set[str]:
    """Functions reachable from roots through calls, roots included."""
    seen, todo = set(), list(roots)
    while todo:
        name = todo.pop()
        if name not in seen:
            seen.add(name)
            todo.extend(callees.get(name, ()))
    return seen


def qemu_command(elf: Path, dfilter: str, log: Path) -> list[str]:
    """QEMU invocation logging one line per executed instruction within dfilter."""
    qemu = _tool("qemu-system-arm")
    version = subprocess.run([qemu, "--version"], capture_output=True, text=True).stdout
    major, minor = map(int, re.search(r"version (\d+)\.(\d+)", version).groups())
    one_insn = ["-accel", "tcg,one-insn-per-tb=on"] if (major, minor) >= (8, 1) else ["-singlestep"]
    return [
        qemu, "-M", "mps2-an386", "-nographic", "-monitor", "none", "-serial", "none",
        "-semihosting-config", "enable=on,target=native", "-kernel", str(elf),
        *one_insn, "-d", "exec,nochain", "-dfilter", dfilter, "-D", str(log),
    ]


def run_trace(elf: Path, timeout: float = 120.0, measured: dict[str, str] | None = None
              ) -> tuple[dict[str, list[int]], list[tuple[str, str]]]:
    """Run the harness traced; return instruction counts per call of each measured
    function (default :data:`MEASURED`), in call order, and the harness's announcements
    (letter, argument; "E" lines too)."""
    measured = MEASURED if measured is None else measured
    syms = symbols(elf)
    callees, returns = call_graph(elf, syms)
    missing = [name for name in measured if name not in syms]
    if missing:
        raise ValueError(f"{elf}: functions {missing} not found")
    ranges = [syms[name] for name in sorted(reachable(list(measured), callees))]
    ret_to = {address: name for name in measured for address in returns[name]}
    dfilter = ",".join([f"0x{a:x}+0x{max(s, 2):x}" for a, s in ranges] + [f"0x{a:x}+0x2" for a in ret_to])
    entries = {syms[name][0]: name for name in measured}

    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "trace.log"
        done = subprocess.run(qemu_command(elf, dfilter, log), capture_output=True, text=True, timeout=timeout)
        if done.returncode != 0:
            raise RuntimeError(f"{elf} under QEMU exited with {done.returncode}: {done.stderr[-500:]}")
        counts: dict[str, list[int]] = defaultdict(list)
        stack: list[list] = []  # [name, count] of the measured calls in progress, innermost last
        with open(log) as trace:
            for line in trace:
                match = TRACE_LINE.match(line)
                if not match:
                    continue
                pc = int(match.group(1), 16)
                if stack and ret_to.get(pc) == stack[-1][0]:
                    name, n = stack.pop()
                    counts[name].append(n)
                    continue
                if pc in entries:  # a measured call, maybe inside another (counted in both)
                    stack.append([entries[pc], 0])
                for call in stack:
                    call[1] += 1
    console = done.stderr + done.stdout
    letters = [f"{letter} " for letter in measured.values()] + ["E ", "R "]
    announced = [tuple(line.split(maxsplit=1)) for line in console.splitlines() if line[:2] in letters]
    return counts, announced


def measure(elf: Path) -> dict:
    """Counts per branch of fastSW, SW's fit a + b n and the counting check.

    Returns
    -------
    dict with keys
        fastsw: {branch: [counts]}, fastsw_min, fastsw_max, fastsw_max_branch (live rule off),
        live_min, live_max, live_max_branch (live rule on),
        sw_n: (N,) segment lengths, sw_count: (N,) counts, sw_a, sw_b, sw_residual_max,
        probe: [(k, count, expected)].
    """
    counts, announced = run_trace(elf)
    by_letter: dict[str, list[str]] = defaultdict(list)
    for letter, arg in announced:
        by_letter[letter].append(arg.strip())
    for name, letter in MEASURED.items():
        if len(by_letter[letter]) != len(counts[name]):
            raise RuntimeError(
                f"{name}: {len(counts[name])} traced calls but {len(by_letter[letter])} announced"
            )
    fastsw: dict[str, list[int]] = defaultdict(list)
    for label, n in zip(by_letter["F"], counts["fastsw_update"]):
        if label != "-":
            fastsw[label].append(n)
    absent = [b for b in FASTSW_BRANCHES + LIVE_BRANCHES if b not in fastsw]
    if absent:
        raise RuntimeError(f"fastsw branches never taken: {absent}")
    every = [n for branch in FASTSW_BRANCHES for n in fastsw[branch]]
    worst = max(FASTSW_BRANCHES, key=lambda b: max(fastsw[b]))
    live = [n for branch in LIVE_BRANCHES for n in fastsw[branch]]
    live_worst = max(LIVE_BRANCHES, key=lambda b: max(fastsw[b]))
    sw = [(int(a), n) for a, n in zip(by_letter["S"], counts["sw_update"]) if a != "-"]
    sw_n = np.array([a for a, _ in sw])
    sw_count = np.array([n for _, n in sw])
    fit = (sw_n >= 1) & (sw_n <= 200)
    design = np.c_[np.ones(fit.sum()), sw_n[fit]]
    (a, b), *_ = np.linalg.lstsq(design, sw_count[fit].astype(float), rcond=None)
    residual = np.abs(design @ [a, b] - sw_count[fit]).max()
    probe = [(int(k), n, 3 + 3 * int(k)) for k, n in zip(by_letter["K"], counts["icount_probe"])]
    return {
        "fastsw": dict(fastsw), "fastsw_min": min(every), "fastsw_max": max(every),
        "fastsw_max_branch": worst, "live_min": min(live), "live_max": max(live),
        "live_max_branch": live_worst, "sw_n": sw_n.tolist(), "sw_count": sw_count.tolist(),
        "sw_a": float(a), "sw_b": float(b), "sw_residual_max": float(residual), "probe": probe,
    }


def measure_device(elf: Path) -> dict:
    """The device firmware's instructions per SAMPLE frame (icount_device_main.c).

    Returns
    -------
    dict with keys point, none: [counts] of the samples that did / did not make a point;
    max, mean: over all samples.
    """
    counts, announced = run_trace(elf, measured=DEVICE_MEASURED)
    outcomes = [arg.strip() for letter, arg in announced if letter == "E"]
    calls = counts["icount_device_frame"]
    if len(outcomes) != len(calls) or not calls:
        raise RuntimeError(f"icount_device_frame: {len(calls)} traced calls but {len(outcomes)} announced")
    by = {kind: [n for n, o in zip(calls, outcomes) if o == kind] for kind in ("point", "none")}
    return {**by, "max": max(calls), "mean": float(np.mean(calls))}


def report_device(result: dict) -> str:
    lines = ["device firmware per SAMPLE frame: link decode, fastSW live, point encoding and framing "
             "(Cortex-M4, QEMU mps2-an386; the transport's write not counted)",
             f"{'sample':<12}{'calls':>7}{'min':>7}{'mean':>8}{'max':>7}"]
    for kind, label in (("none", "no point"), ("point", "a point")):
        c = result[kind]
        if c:
            lines.append(f"{label:<12}{len(c):>7}{min(c):>7}{np.mean(c):>8.0f}{max(c):>7}")
    lines.append(f"device mean instructions per sample: {result['mean']:.0f}")
    lines.append(f"device max instructions per sample: {result['max']}")
    return "\n".join(lines)


def measure_imu(elf: Path) -> dict:
    """Instructions per raw sample of VQF 6D alone and of the device's pipeline, and per device
    sample: the pipeline calls since the previous device sample, this one's included
    (icount_imu_main.c).

    Returns
    -------
    dict with keys vqf6d: [counts per raw sample]; imu: {outcome: [counts]} (none, sample, point);
    per_output: [counts per device sample]; rest: whether VQF detected the still phase.
    """
    counts, announced = run_trace(elf, timeout=600.0, measured=IMU_MEASURED)
    outcomes = [arg.strip() for letter, arg in announced if letter == "E"]
    calls = counts["icount_imu"]
    n = len(calls)
    gyr, acc = counts["lsw_vqf_gyr"][-n:], counts["lsw_vqf_acc"][-n:]  # the warm-up's calls come first
    if len(outcomes) != n or len(gyr) != n or len(acc) != n or not calls:
        raise RuntimeError(f"icount_imu: {n} traced calls but {len(outcomes)} announced")
    console_rest = [arg.strip() for letter, arg in announced if letter == "R"]
    imu = {kind: [n for n, o in zip(calls, outcomes) if o == kind] for kind in ("none", "sample", "point")}
    per_output, since = [], 0
    for n, outcome in zip(calls, outcomes):
        since += n
        if outcome != "none":
            per_output.append(since)
            since = 0
    return {"vqf6d": [g + a for g, a in zip(gyr, acc)], "imu": imu,
            "per_output": per_output[1:], "rest": console_rest == ["rest"]}  # the first: one raw sample


def report_imu(result: dict) -> str:
    rows = [("VQF 6D alone, per raw sample", result["vqf6d"])]
    rows += [(f"pipeline, raw sample: {label}", result["imu"][kind])
             for kind, label in (("none", "no device sample"), ("sample", "device sample"), ("point", "a point"))]
    rows.append(("pipeline, per device sample", result["per_output"]))
    lines = ["raw-sample pipeline (lsw_imu.h), instructions (Cortex-M4, QEMU mps2-an386; 200 Hz raw, 50 Hz device, "
             "fastSW live 5 deg)", f"{'':<40}{'calls':>7}{'min':>8}{'mean':>8}{'max':>8}"]
    for label, c in rows:
        if c:
            lines.append(f"{label:<40}{len(c):>7}{min(c):>8}{np.mean(c):>8.0f}{max(c):>8}")
    lines.append(f"rest detected in the still phase: {'yes' if result['rest'] else 'no'}")
    lines.append(f"vqf 6d max instructions per raw sample: {max(result['vqf6d'])}")
    lines.append(f"imu max instructions per device sample: {max(result['per_output'])}")
    return "\n".join(lines)


def report(result: dict) -> str:
    """The printed table."""
    lines = ["fastsw_update, instructions per call (Cortex-M4, QEMU mps2-an386)",
             f"{'branch':<15}{'calls':>7}{'min':>7}{'max':>7}"]
    for branch in FASTSW_BRANCHES:
        c = result["fastsw"][branch]
        lines.append(f"{branch:<15}{len(c):>7}{min(c):>7}{max(c):>7}")
    lines.append(f"{'all':<15}{sum(len(result['fastsw'][b]) for b in FASTSW_BRANCHES):>7}"
                 f"{result['fastsw_min']:>7}{result['fastsw_max']:>7}   max: {result['fastsw_max_branch']}")
    lines.append("")
    lines.append("fastsw_update with the live rule on, instructions per call")
    lines.append(f"{'branch':<20}{'calls':>7}{'min':>7}{'max':>7}")
    for branch in LIVE_BRANCHES:
        c = result["fastsw"][branch]
        lines.append(f"{branch:<20}{len(c):>7}{min(c):>7}{max(c):>7}")
    lines.append(f"{'all':<20}{sum(len(result['fastsw'][b]) for b in LIVE_BRANCHES):>7}"
                 f"{result['live_min']:>7}{result['live_max']:>7}   max: {result['live_max_branch']}")
    lines.append("")
    lines.append("sw_update, instructions per call vs samples n in the current segment")
    counts = dict(zip(result["sw_n"], result["sw_count"]))
    lines.append("  ".join(f"n={n}: {counts[n]}" for n in (1, 2, 10, 50, 100, 200) if n in counts))
    lines.append(f"least-squares fit n=1..200: {result['sw_a']:.1f} + {result['sw_b']:.2f} n "
                 f"(max residual {result['sw_residual_max']:.1f}; paper: 161 + 35 n)")
    lines.append("")
    checks = ", ".join(f"k={k}: {n} (expected {e})" for k, n, e in result["probe"])
    lines.append(f"counting check, icount_probe = 3 + 3k: {checks}")
    lines.append(f"fastsw max instructions per sample: {result['fastsw_max']}")
    lines.append(f"fastsw live max instructions per sample: {result['live_max']}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("elf", type=Path, help="build/icount.elf")
    parser.add_argument("--json", action="store_true", help="print the measurements as JSON")
    parser.add_argument("--device", action="store_true", help="ELF is build/icount_device.elf: the device firmware")
    parser.add_argument("--imu", action="store_true", help="ELF is build/icount_imu.elf: the raw-sample pipeline")
    args = parser.parse_args(argv)
    if args.imu:
        result = measure_imu(args.elf)
        print(json.dumps(result) if args.json else report_imu(result))
        return 0
    if args.device:
        result = measure_device(args.elf)
        print(json.dumps(result) if args.json else report_device(result))
        return 0
    result = measure(args.elf)
    bad = [p for p in result["probe"] if p[1] != p[2]]
    print(json.dumps(result) if args.json else report(result))
    if bad:
        print(f"error: instruction counting is off: {bad}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
