"""Performance regression check: the same benchmarks for two git revisions, back to back on
this machine, and the ratios HEAD / baseline.

Each revision is checked out in a temporary worktree and installed (its C kernel built) into a
virtual environment of its own that borrows this environment's dependencies; then, per
revision, in turn: the soak (``bench/soak.py``, shortened), the aggregator core bench
(``bench/pipeline.py core``; again with ``--no-joint-angles`` where the revision has joint angles,
and what the angles add to its CPU, and with ``--layout full`` where it has the whole-body layout) and the emulator bench (``bench/pipeline.py emulator``);
then the core bench ``--core-rounds`` times more, the two revisions in turn, its figure being each
one's median (a single run of a revision has varied by a quarter from one run to the next). Run it
before resolving any change that touches the device, router or aggregator path
(docs/benchmarks.md, "Regression check").

    python bench/regress.py --base edac059            # HEAD vs edac059, about 12 minutes
    python bench/regress.py --base main --head HEAD --soak-minutes 1 --devices 1000
    python bench/regress.py --base 8a3b1d4 --live-rate 10   # live frames as older tables ran them
    python bench/regress.py --base main --layouts 3   # only the core bench's cost per device, paper10 vs full

Both the soak and the core bench run with live frames at ``--live-rate`` (default 50 Hz, as
``make run`` runs the aggregator), on both revisions where their benches have the flag.
"""
from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import sysconfig
import tempfile
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def install(rev: str, where: Path) -> Path:
    """Check ``rev`` out at ``where`` and install it into ``where/.venv``; returns its python."""
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-f", str(where), rev], check=True,
                   capture_output=True)
    venv.create(where / ".venv", with_pip=False)
    python = where / ".venv" / "bin" / "python"
    site = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True).stdout.strip()
    Path(site, "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")  # this env's dependencies
    subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "-q", "--no-deps",
                    "-e", str(where)], check=True, capture_output=True)
    return python


def run(python: Path, cwd: Path, *args: str) -> str:
    out = subprocess.run([str(python), *args], cwd=cwd, capture_output=True, text=True, timeout=3600)
    if out.returncode not in (0, 1):
        raise SystemExit(f"{' '.join(args)} failed in {cwd}:\n{out.stdout[-2000:]}\n{out.stderr[-2000:]}")
    return out.stdout


def table_row(text: str, column: str, value: str) -> dict[str, float]:
    """The row of a printed markdown table whose ``column`` is ``value``: {header: number} (the
    leading number of each cell; units and % dropped)."""
    header: list[str] = []
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if column in cells:
            header = cells
        elif header and len(cells) >= len(header) and cells[header.index(column)] == value:
            out = {}
            for name, cell in zip(header, cells):
                m = re.match(r"-?[\d.]+", cell.replace(",", ""))
                if m:
                    out[name] = float(m[0])
            return out
    return {}


def numbers(python: Path, cwd: Path, args) -> dict[str, float]:
    """The figures compared, from one revision's runs."""
    fig: dict[str, float] = {}
    soak_json = cwd / "soak.json"
    live = ("--live-rate", f"{args.live_rate:g}")
    run(python, cwd, "bench/soak.py", "--devices", str(args.devices), "--minutes", f"{args.soak_minutes:g}",
        "--json", str(soak_json), *(live if "--live-rate" in (cwd / "bench/soak.py").read_text() else ()))
    soak = json.loads(soak_json.read_text())
    r = soak["results"]
    fig["soak: emulator late ticks %"] = r["emulator late ticks %"]
    fig["soak: aggregator late ticks % after warm-up"] = r["aggregator late ticks % after warm-up"]
    fig["soak: aggregator busy %"] = r["aggregator busy % of wall time (main loop)"]
    fig["soak: aggregator CPU %"] = soak["cpu"].get("aggregator", float("nan"))
    threads = soak.get("aggregator threads cpu", {})  # (revisions whose soak records them)
    fig["soak: aggregator CPU % of its Python thread"] = threads.get("python", float("nan"))
    fig["soak: aggregator CPU % of Zenoh's threads"] = sum(v for k, v in threads.items() if k != "python") if threads else float("nan")
    fig["soak: emulators CPU %"] = sum(v for k, v in soak["cpu"].items() if k.startswith("emulator"))
    fig["soak: router CPU %"] = soak["cpu"].get("router", float("nan"))
    fig["soak: aggregator RSS after warm-up MiB"] = max(soak["rss"]["aggregator"])
    fig["soak: aggregator max backlog"] = r["aggregator max backlog overall"]
    # the same live frame rate on both sides: revisions before --live-rate fixed 10 Hz in this bench
    rate = live if "--live-rate" in (cwd / "bench/pipeline.py").read_text() else ()
    core = table_row(run(python, cwd, "bench/pipeline.py", "core", "--subjects", "200", "--seconds",
                         f"{args.seconds:g}", *rate), "subjects", "200")
    with_angles = core.get("CPU per second of stream", float("nan"))
    fig[f"core bench, 200 subjects, live frames at {args.live_rate:g} Hz: CPU per second of stream"] = with_angles
    if "--no-joint-angles" in (cwd / "bench/pipeline.py").read_text():  # revisions with joint angles
        bare = table_row(run(python, cwd, "bench/pipeline.py", "core", "--subjects", "200", "--seconds",
                             f"{args.seconds:g}", *rate, "--no-joint-angles"), "subjects", "200")
        without = bare.get("CPU per second of stream", float("nan"))
        fig["core bench, 200 subjects: CPU per second of stream without joint angles"] = without
        fig["core bench, 200 subjects: CPU joint angles add, % of that"] = 100 * (with_angles / without - 1)
    if "--layout" in (cwd / "bench/pipeline.py").read_text():  # revisions with the whole-body layout
        full = table_row(run(python, cwd, "bench/pipeline.py", "core", "--subjects", "200", "--seconds",
                             f"{args.seconds:g}", *rate, "--layout", "full"), "subjects", "200")
        fig["core bench, 200 subjects, full layout (15 devices each): CPU per second of stream"] = \
            full.get("CPU per second of stream", float("nan"))
    emu = table_row(run(python, cwd, "bench/pipeline.py", "emulator", "--devices", "2000", "--seconds",
                        f"{args.seconds:g}"), "devices", "2000")
    for name in ("late ticks", "emulator CPU", "its tick loop's thread", "router CPU"):
        fig[f"emulator bench, 2,000 devices: {name} %"] = emu.get(name, float("nan"))
    return fig


LAYOUTS = ("paper10", "full")
"""The layouts whose cost per device ``--layouts`` compares (10 and 15 devices a subject)."""


def layout_costs(pythons: dict[str, Path], dirs: dict[str, Path], args) -> None:
    """``--layouts N``: the core bench (200 subjects) on each of :data:`LAYOUTS`, base then head, N
    rounds back to back; prints each run's CPU per device (us of CPU per second of stream per
    device), ``full`` / ``paper10`` per device in each round, and the medians."""
    import statistics
    rate = ("--live-rate", f"{args.live_rate:g}")
    per: dict[tuple[str, str], list[float]] = {}
    print("\n| round | revision | layout | devices | CPU per second of stream | us per device-second |\n"
          "|---:|---|---|---:|---:|---:|")
    for k in range(args.layouts):
        for rev in (args.base, args.head):
            for layout in LAYOUTS:
                row = table_row(run(pythons[rev], dirs[rev], "bench/pipeline.py", "core", "--subjects", "200",
                                    "--seconds", f"{args.seconds:g}", *rate, "--layout", layout), "subjects", "200")
                cpu, devices = row.get("CPU per second of stream", float("nan")), row.get("devices", float("nan"))
                per.setdefault((rev, layout), []).append(1e4 * cpu / devices)
                print(f"| {k + 1} | {rev} | {layout} | {devices:.0f} | {cpu:.1f} % | {per[rev, layout][-1]:.1f} |",
                      flush=True)
    print(f"\n| revision | {' | '.join(f'{x} us per device-second (median)' for x in LAYOUTS)} | "
          f"{LAYOUTS[1]} / {LAYOUTS[0]} per device, each round | median |\n|---|---:|---:|---|---:|")
    for rev in (args.base, args.head):
        ratios = [f / p for p, f in zip(per[rev, LAYOUTS[0]], per[rev, LAYOUTS[1]])]
        print(f"| {rev} | {' | '.join(f'{statistics.median(per[rev, x]):.1f}' for x in LAYOUTS)} | "
              f"{', '.join(f'{r:.2f}' for r in ratios)} | **{statistics.median(ratios):.2f}** |")
    for layout in LAYOUTS:
        ratios = [h / b for b, h in zip(per[args.base, layout], per[args.head, layout])]
        print(f"\n{layout}: {args.head} / {args.base} per device, each round "
              f"{', '.join(f'{r:.2f}' for r in ratios)}, median {statistics.median(ratios):.2f}")


def core_rounds(pythons: dict[str, Path], dirs: dict[str, Path], first: dict[str, float], args) -> dict[str, float]:
    """The core bench (200 subjects, live frames at ``--live-rate``) ``--core-rounds`` times more,
    base and head in turn, so that both meet the same drift of the machine's speed; prints every
    run and returns each revision's median over its runs (``first``: the run :func:`numbers` made)."""
    import statistics
    rate = ("--live-rate", f"{args.live_rate:g}")
    runs = {rev: [value] for rev, value in first.items()}
    print(f"\n| core bench run | {args.base} | {args.head} | ratio |\n|---:|---:|---:|---:|")
    for k in range(args.core_rounds + 1):
        if k:
            for rev in runs:
                with_rate = rate if "--live-rate" in (dirs[rev] / "bench/pipeline.py").read_text() else ()
                row = table_row(run(pythons[rev], dirs[rev], "bench/pipeline.py", "core", "--subjects", "200",
                                    "--seconds", f"{args.seconds:g}", *with_rate), "subjects", "200")
                runs[rev].append(row.get("CPU per second of stream", float("nan")))
        b, h = runs[args.base][-1], runs[args.head][-1]
        print(f"| {k + 1} | {b:.1f} % | {h:.1f} % | {h / b:.2f} |", flush=True)
    return {rev: statistics.median(v) for rev, v in runs.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", required=True, help="baseline revision (e.g. a tag, edac059, main)")
    parser.add_argument("--head", default="HEAD", help="revision to check (default HEAD)")
    parser.add_argument("--devices", type=int, default=2000, help="soak devices (default 2000)")
    parser.add_argument("--soak-minutes", type=float, default=3.0, help="soak duration (default 3)")
    parser.add_argument("--seconds", type=float, default=20.0, help="per pipeline bench row (default 20)")
    parser.add_argument("--live-rate", type=float, default=50.0,
                        help="the aggregator's live frame rate in the soak and the core bench, Hz (default 50, "
                             "make run's; revisions whose core bench lacks the flag ran it at 10)")
    parser.add_argument("--layouts", type=int, default=0, metavar="N",
                        help="instead of the checks above: the core bench's cost per device on paper10 and full, "
                             "both revisions, N rounds back to back")
    parser.add_argument("--core-rounds", type=int, default=2, metavar="N",
                        help="the core bench N times more, the revisions in turn; its figure is then the median of "
                             "each revision's N + 1 runs (default 2; 0: its one run)")
    args = parser.parse_args(argv)
    results = {}
    with tempfile.TemporaryDirectory(prefix="limbstream-regress-") as tmp:
        try:
            pythons = {rev: install(rev, Path(tmp) / name) for rev, name in ((args.base, "base"), (args.head, "head"))}
            if args.layouts:
                layout_costs(pythons, {args.base: Path(tmp) / "base", args.head: Path(tmp) / "head"}, args)
                return 0
            for rev, name in ((args.base, "base"), (args.head, "head")):
                print(f"running {rev} ...", flush=True)
                results[rev] = numbers(pythons[rev], Path(tmp) / name, args)
            if args.core_rounds:  # the core bench's figure: the median of each revision's runs
                core = next(k for k in results[args.head] if k.startswith("core bench, 200 subjects, live"))
                dirs = {args.base: Path(tmp) / "base", args.head: Path(tmp) / "head"}
                medians = core_rounds(pythons, dirs, {rev: results[rev][core] for rev in dirs}, args)
                for rev, median in medians.items():
                    results[rev][core] = median
        finally:
            for name in ("base", "head"):
                subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(Path(tmp) / name)],
                               capture_output=True)
    base, head = results[args.base], results[args.head]
    print(f"\n| measure | {args.base} | {args.head} | ratio |\n|---|---|---|---|")
    for key in base | head:  # (a figure only one revision has shows with nan for the other)
        b, h = base.get(key, float("nan")), head.get(key, float("nan"))
        ratio = h / b if b else float("nan")
        print(f"| {key} | {b:.3g} | {h:.3g} | {ratio:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
