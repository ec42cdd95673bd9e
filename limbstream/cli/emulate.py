"""``limbstream emulate``: the flags of emulated IMU devices (subjects x segments) in one
process (the part: :mod:`limbstream.device_emulator.main`)."""
from __future__ import annotations

import argparse
import copy
import dataclasses
import logging
import os
import threading
from pathlib import Path

from limbstream import calibration, wire
from limbstream.cli import flags
from limbstream.device_emulator import main as emulator
from limbstream.device.clocks import ClockSettings
from limbstream.device.host import HostSettings
from limbstream.device_emulator.emulator import EmulatorSettings
from limbstream.device.feeds import GeneratorFeed, LoopFeed
from limbstream.device.readings import RawFeed
from limbstream.device_emulator.main import subject_names
from limbstream.sources import MotionFileError, load
from limbstream.sources.bvh_loop import looped_motion, walks_on
from limbstream.sources.generator import GeneratorSource

PROG = "limbstream emulate"


def build_feeds(args: argparse.Namespace, scripted: bool = False) -> dict:
    """{subject: feed} from --source: the generator (seed = subject number, the body of
    ``--layout``) or a motion file, whose clips the subjects share in turn (:func:`clip_of`);
    ``scripted``: each begins with the calibration script (limbstream.calibration). With ``--imu
    raw``: raw sensor feeds (each with the script, every subject from its clip's start). Each
    feed's ``body`` (its wearer's dimensions, which its devices announce) is its clip's own (a BVH
    file's skeleton; the generator's: None for paper10, the default adult, else its layout's
    default body) unless ``--height-m`` or ``--body`` give the subjects theirs, in turn."""
    names = subject_names(args.subjects, args.first_subject, args.subject_prefix)
    feeds = raw_feeds(args, names) if args.imu == "raw" else motion_feeds(args, names, scripted)
    given = flags.bodies(args) or []
    for i, feed in enumerate(feeds.values() if given else ()):
        feed.body = given[(args.first_subject + i - 1) % len(given)]
    return feeds


def motion_feeds(args: argparse.Namespace, names: list[str], scripted: bool) -> dict:
    """{subject: feed} of orientations (see :func:`build_feeds`)."""
    feeds: dict[str, GeneratorFeed | LoopFeed]
    if args.source == "generator":
        layout = flags.layout(args)
        feeds = {name: GeneratorFeed(seed=args.seed + args.first_subject + i, fs=args.rate, noise_deg=args.noise_deg,
                                     layout=layout) for i, name in enumerate(names)}
    else:
        motions = source_motions(args)
        feeds, clips = {}, {}
        for i, name in enumerate(names):
            clip, start = clip_of(args.first_subject + i, len(motions), args.same_start)
            if clip not in clips:  # one feed's arrays per clip, its subjects each at their own place in it
                clips[clip] = LoopFeed(motions[clip], args.rate, once=args.once)
            feeds[name] = clips[clip].starting_at(start)
    if not scripted:
        return feeds
    return {name: calibration.ScriptedFeed(f, args.rate, None if f.length is not None or not hasattr(f, "q")
                                           else len(f.q)) for name, f in feeds.items()}


def raw_feeds(args: argparse.Namespace, names: list[str]) -> dict[str, RawFeed]:
    """{subject: RawFeed} of ``--imu raw`` (see :func:`build_feeds`)."""
    if args.source == "generator":
        return {name: RawFeed(GeneratorSource(seed=args.seed + args.first_subject + i, fs=args.rate,
                                              layout=flags.layout(args)), args.imu_rate, args.rate)
                for i, name in enumerate(names)}
    motions = source_motions(args)
    feeds, clips = {}, {}
    for i, name in enumerate(names):
        clip = clip_of(args.first_subject + i, len(motions), True)[0]
        if clip not in clips:
            clips[clip] = RawFeed(motions[clip], args.imu_rate, args.rate, once=args.once)
        feeds[name] = copy.copy(clips[clip])  # its readings shared: a clip's subjects all play it from its start
    return feeds


def source_motions(args: argparse.Namespace) -> list:
    """The clips of a motion file ``--source`` (BVH files read onto ``--layout``,
    :func:`flags.source_layout`, with the layout's default body where the file cannot measure its
    bones; one with a root path looped on its own cycle for :data:`LIVE_LOOP_S`, its root walking on,
    unless ``--once``); FlagError when ``--layout`` is not theirs."""
    shape = flags.source_layout(args)
    motions = load(args.source, args.names, layout=shape)
    if not args.once:  # a walk walks on: a BVH clip with a root path looped on its own cycle
        motions = [looped_motion(m, LIVE_LOOP_S, shape or "paper10")[0] if walks_on(m) else m for m in motions]
    if shape is not None:
        motions = [m if m.body is not None else dataclasses.replace(m, body=flags.default_body(args)) for m in motions]
    for motion in motions:
        flags.check_source_layout(args, motion.segments, args.source)
    return motions


LIVE_LOOP_S = 120.0
"""How long a BVH clip with a root path plays looped on its own cycle (:mod:`limbstream.sources.bvh_loop`:
each pass turned and carried on, so a walk walks on without a seam) before it starts again, s."""
START_STEP = (5 ** 0.5 - 1) / 2
"""How far into a clip each further subject that shares it starts, as a fraction of the clip
(the golden ratio's: the starts of any number of subjects stay apart)."""


def clip_of(number: int, clips: int, same_start: bool = False) -> tuple[int, float]:
    """(clip index, start as a fraction of the clip) of subject ``number`` (s01 = 1) over a
    source of ``clips`` clips: the subjects take the clips in turn; the k-th one (from 0) to
    take a clip starts ``k * START_STEP`` (mod 1) into it, or at its start with ``same_start``."""
    k, clip = divmod(number - 1, clips)
    return clip, 0.0 if same_start else (k * START_STEP) % 1.0


GENERATOR_SUBJECTS = 2
"""Subjects on the built-in generator when ``--subjects`` is not given (a motion file or recording
gives one: its own person; more are copies of it)."""


def default_subjects(source: str) -> int:
    """How many subjects ``--source`` gives when ``--subjects`` does not say (see :data:`GENERATOR_SUBJECTS`)."""
    return GENERATOR_SUBJECTS if source == "generator" else 1


def add_arguments(parser: argparse.ArgumentParser) -> None:
    env = os.environ.get
    parser.add_argument("--subjects", type=int, default=env("LIMBSTREAM_SUBJECTS"),
                        help="number of subjects, each with a device per segment of the source (env "
                             "LIMBSTREAM_SUBJECTS; default: 2 on the generator, 1 on a motion file or recording, "
                             "whose person it is; more are copies)")
    parser.add_argument("--first-subject", type=int, default=1, help="number of the first subject (s01 = 1)")
    parser.add_argument("--subject-prefix", default=env("LIMBSTREAM_SUBJECT_PREFIX", "s"),
                        help="subject name prefix (env LIMBSTREAM_SUBJECT_PREFIX; default s: s01, s02, ...); "
                             "'auto' = '<hostname>-s', distinct for each scaled container")
    parser.add_argument("--source", default=env("LIMBSTREAM_SOURCE", "generator"),
                        help="'generator' (built-in, default) or a motion file/folder (.npz, .bvh, .csv, .txt) "
                             "(env LIMBSTREAM_SOURCE)")
    add_source_arguments(parser)
    parser.add_argument("--once", action="store_true", help="play a file source once, then flush and idle")
    parser.add_argument("--duration", type=float, default=None, help="stop after this many seconds of device time")
    parser.add_argument("--rate", type=float, default=wire.DEVICE_RATE_HZ,
                        help=f"device sample rate, Hz (default {wire.DEVICE_RATE_HZ:g})")
    parser.add_argument("--speed", type=float, default=1.0, help="time scale (default 1 = real time)")
    flags.add_device_config(parser)  # --threshold, --max-len: the device tunables
    parser.add_argument("--no-truth", dest="truth", action="store_false", help="do not publish the truth tap")
    parser.add_argument("--raw-batch", type=int, default=25,
                        help="samples per truth-tap batch (default 25; one message per subject and batch)")
    parser.add_argument("--cache", type=int, default=512, help="segment points kept per device for recovery")
    parser.add_argument("--seed", type=int, default=0, help="generator seed offset")
    parser.add_argument("--firmware", action="store_true",
                        help="run each device's firmware under QEMU (one process per device, fed over its serial link) "
                             "instead of the host's kernel: the same points (docs/kernel.md, 'Device firmware')")
    parser.add_argument("--firmware-elf", type=Path, default=None,
                        help="the device firmware to run (default: build firmware_c/build/device.elf with make)")
    parser.add_argument("--noise-deg", type=float, default=0.0, help="generator sensor noise, RMS degrees")
    add_clock_arguments(parser)
    flags.add_sensor_model(parser)
    flags.add_layout(parser)
    flags.add_body(parser)
    parser.add_argument("-v", "--verbose", action="store_true")
    flags.add_zenoh(parser)


def add_source_arguments(parser: argparse.ArgumentParser) -> None:
    """The flags of a file source that ``limbstream up`` passes on (``--names``, ``--same-start``)."""
    flags.add_names(parser)
    parser.add_argument("--same-start", action="store_true",
                        help="subjects that share a clip play it in step (default: each further one starts "
                             f"{100 * START_STEP:.1f} %% of the clip further in)")


def add_clock_arguments(parser: argparse.ArgumentParser, tuning: bool = True) -> None:
    """The device clock and time sync flags; ``limbstream up`` takes those without ``tuning``
    (the sync's poll, holdover and wait) and passes them on (:func:`clock_flags`)."""
    group = parser.add_argument_group("device clocks (docs/reliability.md, 'Device clocks')")
    group.add_argument("--clock-offset-ms", type=float, default=0.0, metavar="MAX",
                       help="each device's clock is off by an offset drawn uniform in +-MAX ms (default 0)")
    group.add_argument("--clock-drift-ppm", type=float, default=0.0, metavar="MAX",
                       help="each device's clock drifts by a rate drawn uniform in +-MAX ppm (default 0; <= 1000)")
    group.add_argument("--clock-jitter-us", type=float, default=0.0, metavar="J",
                       help="every clock read is off by uniform +-J us (default 0; <= 1000)")
    group.add_argument("--clock-seed", type=int, default=0, help="seed of the clock draws (default 0)")
    group.add_argument("--no-sync", dest="sync", action="store_false",
                       help="devices do not synchronise with the time service (they stamp with their own clock)")
    if not tuning:
        return
    group.add_argument("--sync-poll-s", type=float, default=512.0,
                       help="longest interval between a device's time exchanges, device seconds (default 512)")
    group.add_argument("--sync-holdover-s", type=float, default=600.0,
                       help="a device without a valid time answer for this long reports itself unsynced (default 600)")
    group.add_argument("--sync-wait-s", type=float, default=10.0,
                       help="at start, wait at most this long for the first time answers (default 10)")
    group.add_argument("--time-anchor", type=float, default=None, metavar="EPOCH_S",
                       help="with --speed != 1: the instant (Unix seconds) the scaled time agrees with the host "
                            "clock; the time service needs the same (default: the start)")


def clock_flags(args: argparse.Namespace) -> list[str]:
    """The ``emulate`` arguments that give the clock flags of ``args`` (``add_clock_arguments``
    without tuning)."""
    argv = ["--clock-offset-ms", f"{args.clock_offset_ms:g}", "--clock-drift-ppm", f"{args.clock_drift_ppm:g}",
            "--clock-jitter-us", f"{args.clock_jitter_us:g}", "--clock-seed", str(args.clock_seed)]
    return argv if args.sync else argv + ["--no-sync"]


def check_clock(args: argparse.Namespace) -> None:
    """ValueError naming the first bad flag of :func:`add_clock_arguments` without tuning."""
    for ok, message in (
        (0 <= args.clock_offset_ms <= 1e7, f"--clock-offset-ms must be in 0..1e7, got {args.clock_offset_ms}"),
        (0 <= args.clock_drift_ppm <= 1000, f"--clock-drift-ppm must be in 0..1000, got {args.clock_drift_ppm}"),
        (0 <= args.clock_jitter_us <= 1000, f"--clock-jitter-us must be in 0..1000, got {args.clock_jitter_us}"),
    ):
        if not ok:
            raise ValueError(message)


def clock_settings(args: argparse.Namespace) -> ClockSettings:
    """ClockSettings from the flags; SystemExit naming a bad one."""
    try:
        check_clock(args)
    except ValueError as exc:
        raise SystemExit(f"{PROG}: error: {exc}") from None
    checks = [
        (args.sync_poll_s >= 1, f"--sync-poll-s must be >= 1, got {args.sync_poll_s}"),
        (args.sync_holdover_s > 0, f"--sync-holdover-s must be > 0, got {args.sync_holdover_s}"),
        (args.sync_wait_s >= 0, f"--sync-wait-s must be >= 0, got {args.sync_wait_s}"),
    ]
    for ok, message in checks:
        if not ok:
            raise SystemExit(f"limbstream emulate: error: {message}")
    return ClockSettings(offset_ms=args.clock_offset_ms, drift_ppm=args.clock_drift_ppm,
                         jitter_us=args.clock_jitter_us, seed=args.clock_seed, sync=args.sync,
                         poll_s=args.sync_poll_s, holdover_s=args.sync_holdover_s, wait_s=args.sync_wait_s)


def validate(args: argparse.Namespace) -> None:
    """Clear errors for bad flag values (SystemExit with a message); ``--subjects`` not given: the
    source's default (:func:`default_subjects`)."""
    if args.subjects is None:
        args.subjects = default_subjects(args.source)
    checks = [
        (args.subjects >= 1, f"--subjects must be >= 1, got {args.subjects}"),
        (args.rate > 0, f"--rate must be > 0, got {args.rate}"),
        (args.speed > 0, f"--speed must be > 0, got {args.speed}"),
        (1 <= args.raw_batch <= wire.MAX_RAW_BATCH, f"--raw-batch must be in 1..{wire.MAX_RAW_BATCH}"),
        (args.cache >= 1, f"--cache must be >= 1, got {args.cache}"),
    ]
    for ok, message in checks:
        if not ok:
            raise SystemExit(f"limbstream emulate: error: {message}")
    flags.layout(args)  # FlagError: one line, exit status 2
    flags.bodies(args)


def run(args: argparse.Namespace, stop: threading.Event | None = None) -> int:
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(message)s")
    validate(args)
    try:
        sensors = flags.sensor_model(args)
        feeds = build_feeds(args, scripted=sensors.on)
    except (MotionFileError, ValueError) as exc:
        raise SystemExit(f"limbstream emulate: error: {exc}") from None
    settings = settings_of(args, sensors)
    if args.firmware:
        return run_firmware(args, feeds, settings, stop)
    if settings.imu is not None and settings.clock.modelled:
        raise SystemExit("limbstream emulate: error: --imu raw samples on the feed's own clock: device clock models "
                         "(--clock-offset-ms, --clock-drift-ppm, --clock-jitter-us) are not available with it")
    return emulator.run(feeds, settings, flags.session_settings(args, PROG), args.duration, args.verbose, stop)


def settings_of(args: argparse.Namespace, sensors) -> EmulatorSettings:
    """The EmulatorSettings of the flags. The emulator's truth tap goes out one message per subject
    (its devices sample together); firmware devices each send their own, per device."""
    return EmulatorSettings(HostSettings(fs=args.rate, config=flags.device_config(args), truth=args.truth,
                                         raw_batch=args.raw_batch, truth_by_subject=not args.firmware,
                                         cache=args.cache),
                            speed=args.speed, clock=clock_settings(args),
                            anchor_us=None if args.time_anchor is None else args.time_anchor * 1e6,
                            clock_id=args.first_subject, sensors=sensors, imu=flags.imu_model(args),
                            imu_rate_hz=args.imu_rate, vqf_precision=args.vqf_precision)


def run_firmware(args: argparse.Namespace, feeds: dict, settings: EmulatorSettings,
                 stop: threading.Event | None) -> int:
    """``--firmware``: the devices' firmware under QEMU (limbstream.services.gateway.firmware_devices).
    Each device takes its feed's own samples (with ``--imu raw`` its sensor's readings, the
    emulator's): modelled clocks and the orientation sensor model are refused."""
    from limbstream.device.readings import RawSensors
    from limbstream.services.gateway import firmware, firmware_devices
    if settings.clock.modelled or (settings.sensors.on and settings.imu is None):
        raise SystemExit("limbstream emulate: error: --firmware feeds every device its motion's own samples: "
                         "device clock models (--clock-offset-ms, --clock-drift-ppm, --clock-jitter-us) and "
                         "modelled sensor errors are not available with it (raw sensors are: --imu raw)")
    try:
        elf = args.firmware_elf or firmware.build(vqf_precision=settings.vqf_precision)
    except (RuntimeError, OSError) as exc:
        raise SystemExit(f"limbstream emulate: error: {exc}") from None
    if not elf.exists():
        raise SystemExit(f"limbstream emulate: error: no firmware at {elf}")
    raw = None
    if settings.imu is not None:  # the sensors as the host emulator draws them (its slot order: longest feeds first)
        ordered = sorted(feeds.values(), key=lambda f: -(f.length or float("inf")))
        raw = RawSensors(ordered, settings.imu, settings.imu_rate_hz, settings.sensors, settings.clock_id)
    return firmware_devices.run(feeds, settings.host, settings.speed, flags.session_settings(args, PROG), elf,
                                args.duration, stop, raw, settings.imu_rate_hz, settings.vqf_precision)
