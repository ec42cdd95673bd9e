"""The flags several commands share and the settings they make, written once: the device
tunables (:data:`limbstream.wire.TUNABLES`), the sensor model (:class:`limbstream.calibration.SensorModel`),
the Zenoh session (:class:`limbstream.zconfig.ZenohSettings`, with the line that says where a
command connects), one list syntax (``A,B,C``) for every flag that takes several values, the
sensor-to-segment mapping of ``--names``; and a command's one-line error.
The core library knows no argparse: its settings are built here from the parsed flags."""
from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

from limbstream import wire, zconfig
from limbstream.sources import names

if TYPE_CHECKING:  # (calibration brings scipy: the commands without sensors start without it)
    from limbstream.body import Body, Layout
    from limbstream.calibration import SensorModel


def fail(prog: str, message: str) -> int:
    """Print ``PROG: error: MESSAGE`` on stderr; the exit status 2 of a bad flag."""
    print(f"{prog}: error: {message}", file=sys.stderr)
    return 2


class FlagError(ValueError):
    """A flag's value, or a combination of flags, that the command cannot run with; the sentence
    names the flag. ``limbstream`` prints it as ``limbstream COMMAND: error: ...``, exit status 2."""


class Given(argparse.Action):
    """``store``, also noting the flag in ``namespace.given`` (a set of dests): a flag that only
    makes sense with another is refused when given without it (:func:`check_shared`)."""

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, values)
        given = set(getattr(namespace, "given", None) or ())
        namespace.given = given | {self.dest}


def given(args: argparse.Namespace, dest: str) -> bool:
    """True if the flag of ``dest`` (declared with ``action=Given``) was on the command line."""
    return dest in (getattr(args, "given", None) or ())


def check_shared(args: argparse.Namespace) -> None:
    """The flags of this module that a command has, checked right after parsing, before it starts
    anything: the Zenoh endpoints, ``--connect-timeout``, ``--zenoh-config``, the raw sensors'
    flags given without ``--imu raw`` and the segments of ``--names`` (:func:`check_names`).
    FlagError naming the first problem."""
    if hasattr(args, "connect"):
        timeout = getattr(args, "connect_timeout", None)
        if timeout is not None and not timeout >= 0:
            raise FlagError(f"--connect-timeout must be >= 0, got {timeout:g}")
        try:
            zconfig.settings(getattr(args, "mode", "client"), args.connect, getattr(args, "listen", ""),
                             args.zenoh_config)
        except ValueError as exc:
            raise FlagError(str(exc)) from None
    if getattr(args, "imu", "raw") != "raw":
        for dest, flag in (("imu_model", "--imu-model"), ("imu_rate", "--imu-rate")):
            if given(args, dest):
                raise FlagError(f"{flag} applies to raw sensors only: add --imu raw")
    if getattr(args, "names", None) is not None:
        check_names(args)


def parse_http(value: str, allow_zero: bool = True) -> tuple[str, int]:
    """``HOST:PORT`` (or ``:PORT``, ``[::1]:PORT``) -> (host, port), an empty host 127.0.0.1;
    FlagError (an argparse error inside a parser) naming ``--http`` otherwise."""
    try:
        host, port = zconfig.split_host_port(value if not value.startswith(":") else "127.0.0.1" + value,
                                             f"--http {value}", allow_zero)
    except ValueError as exc:
        raise FlagError(str(exc)) from None
    return host, port


# ----------------------------------------------------------------------------- device tunables

def tunable(t: wire.Tunable):
    """The argparse type of tunable ``t``: its value, or ArgumentTypeError with :meth:`Tunable.check`'s sentence."""
    def parse(text: str):
        try:
            value = float(text) if t.type is float else int(text)
        except ValueError:
            try:
                value = float(text)
            except ValueError:
                raise argparse.ArgumentTypeError(f"{t.name} must be {t.describe()}, got {text!r}") from None
        try:
            return t.check(value)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    parse.__name__ = t.name
    return parse


def add_device_config(parser: argparse.ArgumentParser, defaults: dict | None = None) -> None:
    """One flag per tunable (``--threshold``, ``--max-len``, ...); ``defaults``: overrides of the
    tunables' defaults, by name."""
    for t in wire.TUNABLES.values():
        default = (defaults or {}).get(t.name, t.default)
        unit = f", {t.unit}" if t.unit else ""
        parser.add_argument(t.flag, dest=t.name, type=tunable(t), default=t.check(default),
                            help=f"{t.help}{unit} ({t.describe()}, default {default:g})")


def device_config(args: argparse.Namespace) -> wire.DeviceConfig:
    """The DeviceConfig of the flags of :func:`add_device_config`."""
    return wire.DeviceConfig(**{name: getattr(args, name) for name in wire.TUNABLES})


# ----------------------------------------------------------------------------- sensor model

def add_sensor_model(parser: argparse.ArgumentParser) -> None:
    """The sensor model's flags (``emulate``, ``up``, ``eval``)."""
    group = parser.add_argument_group("sensors (docs/evaluation.md, 'Calibration'; default: perfect sensors)")
    for flag, text in (("--mounting-deg", "each sensor sits on its segment turned by a random rotation of angle <= MAX"),
                       ("--heading-deg", "each sensor's world frame is turned about the vertical by a uniform +-MAX"),
                       ("--yaw-drift-dps", "... and that heading drifts at a uniform +-MAX deg/s")):
        group.add_argument(flag, type=float, default=0.0, metavar="MAX", help=text)
    group.add_argument("--sensor-seed", type=int, default=0, help="seed of the sensor draws (default 0)")
    group.add_argument("--imu", choices=IMU_KINDS, default="orientation",
                       help="what a device is given: its sensor's orientation (default), or raw gyroscope and "
                            "accelerometer samples it fuses with VQF before fastSW (docs/evaluation.md, 'Raw sensors')")
    group.add_argument("--imu-model", default="ideal", metavar="PART", action=Given,
                       help="with --imu raw: the sensor part whose errors the readings carry (ideal, icm42688p; "
                            "default ideal)")
    group.add_argument("--imu-rate", type=float, default=200.0, metavar="HZ", action=Given,
                       help=f"with --imu raw: the sensors' rate, a whole multiple of the device rate "
                            f"{wire.DEVICE_RATE_HZ:g} Hz (default 200)")
    add_vqf_precision(group)


def add_vqf_precision(parser) -> None:
    """``--vqf-precision`` (every command that fuses raw samples: ``emulate``, ``up``, ``eval``, ``fuse``)."""
    from limbstream.kernel import fusion
    parser.add_argument("--vqf-precision", choices=fusion.VQF_PRECISIONS, default=fusion.DEFAULT_VQF_PRECISION,
                        help="VQF's filter states in single or double precision (docs/kernel.md, \"VQF's precision\"; "
                             f"default the firmware's, {fusion.DEFAULT_VQF_PRECISION})")


IMU_KINDS: tuple[str, ...] = ("orientation", "raw")
"""What ``--imu`` hands a device: its sensor's orientation, or raw samples to fuse."""


def sensor_model(args: argparse.Namespace) -> SensorModel:
    """The SensorModel of the flags (ValueError naming a bad one, or a flag raw sensors do not take)."""
    from limbstream.calibration import SensorModel
    model = SensorModel(args.mounting_deg, args.heading_deg, args.yaw_drift_dps, args.sensor_seed)
    if getattr(args, "imu", "orientation") == "raw":
        from limbstream import imu
        from limbstream.device.readings import raw_per_sample
        if model.yaw_drift_dps > 0:
            raise ValueError("--yaw-drift-dps is the modelled sensors' drift formula; raw sensors drift with their "
                             "gyroscope offset (--imu-model)")
        imu.model(args.imu_model)
        raw_per_sample(args.imu_rate, wire.DEVICE_RATE_HZ)
    return model


def imu_model(args: argparse.Namespace):
    """The part of ``--imu raw`` (:class:`limbstream.imu.ImuModel`), None for ``--imu orientation``."""
    if getattr(args, "imu", "orientation") != "raw":
        return None
    from limbstream import imu
    return imu.model(args.imu_model)


def sensor_model_argv(model: SensorModel, args: argparse.Namespace | None = None) -> list[str]:
    """The flags that give ``model`` and, from ``args``, the raw sensors (for a child process)."""
    argv = ["--mounting-deg", f"{model.mounting_deg:g}", "--heading-deg", f"{model.heading_deg:g}",
            "--yaw-drift-dps", f"{model.yaw_drift_dps:g}", "--sensor-seed", str(model.seed)]
    if args is not None and args.imu == "raw":
        argv += ["--imu", "raw", "--imu-model", args.imu_model, "--imu-rate", f"{args.imu_rate:g}",
                 "--vqf-precision", args.vqf_precision]
    return argv


# ----------------------------------------------------------------------------- heading correction

HEADING_CORRECTIONS = ("off", "joints")
"""``--heading-correction``: none, or each calibrated device whose heading drifts held by the
subject's joints (docs/evaluation.md, "Heading without resets")."""


def add_heading_correction(parser: argparse.ArgumentParser, default: str = "joints") -> None:
    """``--heading-correction off|joints`` (``aggregate``, ``up``, ``eval``)."""
    parser.add_argument("--heading-correction", choices=HEADING_CORRECTIONS, default=default,
                        help="joints: the heading of each calibrated device without a magnetometer (6D) is held by "
                             "the subject's joints, no yaw reset needed; off: none (default %(default)s)")


# ----------------------------------------------------------------------------- zenoh

CONNECT_HINT = (f"set the router's endpoint with --connect or {zconfig.ROUTER_ENV}; `limbstream up` or "
                "`limbstream router` starts one")
"""What a user can do when no router answers (printed after :class:`zconfig.ConnectError`)."""


def add_zenoh(parser: argparse.ArgumentParser, mode: str = "client", timeout: bool = True) -> None:
    """The shared Zenoh flags (``--connect``, ``--listen``, ``--mode``, ``--zenoh-config``,
    ``--connect-timeout``; the router's default from $LIMBSTREAM_ROUTER); without ``timeout``, the
    command bounds the wait for its router with a flag of its own (``watch --timeout``)."""
    group = parser.add_argument_group("zenoh")
    default = os.environ.get(zconfig.ROUTER_ENV, zconfig.DEFAULT_ROUTER if mode != "router" else "")
    group.add_argument("--connect", default=default, metavar="ENDPOINT[,ENDPOINT...]",
                       help=f"router endpoint(s) to connect to (env {zconfig.ROUTER_ENV}; default {default or 'none'})")
    group.add_argument("--listen", default="", metavar="ENDPOINT[,ENDPOINT...]", help="endpoint(s) to listen on")
    group.add_argument("--mode", default=mode, choices=("client", "peer", "router"), help=f"zenoh mode (default {mode})")
    group.add_argument("--zenoh-config", default=os.environ.get(zconfig.CONFIG_ENV, ""), metavar="FILE",
                       help=f"JSON file of extra zenoh settings (key -> value), e.g. TLS/auth (env {zconfig.CONFIG_ENV})")
    if timeout:
        group.add_argument("--connect-timeout", type=float, default=zconfig.CONNECT_TIMEOUT_S, metavar="S",
                           help=f"give up when no router answers within S seconds (default "
                                f"{zconfig.CONNECT_TIMEOUT_S:g}; 0: wait however long it takes)")


def zenoh_settings(args: argparse.Namespace, connect_timeout_s: float | None = None) -> zconfig.ZenohSettings:
    """ZenohSettings from the flags of :func:`add_zenoh`; ``connect_timeout_s`` stands in for
    ``--connect-timeout`` where the command has no such flag (None or 0: wait). FlagError naming
    a bad endpoint, ``--zenoh-config`` or ``--connect-timeout`` (:func:`check_shared` has checked
    them when the command runs from ``limbstream``)."""
    timeout = getattr(args, "connect_timeout", connect_timeout_s)
    if timeout is not None and not timeout >= 0:
        raise FlagError(f"--connect-timeout must be >= 0, got {timeout:g}")
    try:
        return zconfig.settings(args.mode, args.connect, args.listen, args.zenoh_config, timeout)
    except ValueError as exc:
        raise FlagError(str(exc)) from None


def announce(prog: str, settings: zconfig.ZenohSettings) -> None:
    """One line on stderr: where ``prog`` connects, how to change it, and how long it waits."""
    if settings.mode == "router" or not settings.connect:
        return
    wait = ("waiting for it however long it takes" if settings.connect_timeout_s is None
            else f"up to {settings.connect_timeout_s:g} s")
    print(f"{prog}: connecting to {', '.join(settings.connect)} (--connect, env {zconfig.ROUTER_ENV}; {wait})",
          file=sys.stderr, flush=True)


def session_settings(args: argparse.Namespace, prog: str, connect_timeout_s: float | None = None
                     ) -> zconfig.ZenohSettings:
    """:func:`zenoh_settings`, announced (:func:`announce`): what a command calls right before it
    opens its session."""
    settings = zenoh_settings(args, connect_timeout_s)
    announce(prog, settings)
    return settings


# ----------------------------------------------------------------------------- lists and names

T = TypeVar("T")


def comma_list(item: Callable[[str], T]) -> Callable[[str], list[T]]:
    """An argparse ``type`` that reads ``A,B,C`` (spaces around the commas allowed) with ``item``
    for each value; ``item`` raises ValueError or ArgumentTypeError with its own sentence."""

    def parse(text: str) -> list[T]:
        values = []
        for part in (p.strip() for p in text.split(",")):
            if not part:
                continue
            try:
                values.append(item(part))
            except ValueError as exc:
                raise argparse.ArgumentTypeError(str(exc)) from None
        if not values:
            raise argparse.ArgumentTypeError(f"no value in {text!r}")
        return values

    return parse


def sensor_names(text: str) -> dict[str, str]:
    """The ``--names`` mapping (:func:`limbstream.sources.names.parse`), as an argparse type."""
    try:
        return names.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_names(parser: argparse.ArgumentParser) -> None:
    """``--names NAME|FILE|SENSOR=SEGMENT,...``: which segment each sensor of an IMU recording
    measures (the mapping itself: :mod:`limbstream.sources.names`)."""
    parser.add_argument("--names", type=sensor_names, default=None, metavar="NAME|FILE|SENSOR=SEGMENT,...",
                        help="which segment each sensor of an IMU recording (or joint of a BVH file) measures: "
                             f"a named mapping ({', '.join(names.NAMED)}), a file of SENSOR=SEGMENT lines, or a "
                             "list (SENSOR: a file name without extension, e.g. an Xsens serial number, or a BVH "
                             "joint; SEGMENT: a segment of --layout, a layout file's own too, else of a built-in "
                             "layout; default: x-IMU3 file names, e.g. Left_Upper.csv -> l_thigh; BVH: the CMU, "
                             "Mixamo and Left/L/Right/R joint names, under the joints a mapping names)")


def body_layout(text: str):
    """The ``--layout`` layout (:func:`limbstream.body.layout`: a built-in's name or a
    ``.toml``/``.json`` file), as an argparse type."""
    from limbstream.body import layout

    try:
        return layout(text)
    except (ValueError, OSError) as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_source_layout(parser: argparse.ArgumentParser, default_text: str) -> None:
    """``--layout paper10|full|FILE`` of a command that reads sources (``eval``): the body layout a
    source is read onto (docs/body.md), a :class:`~limbstream.body.Layout` (None: not given)."""
    parser.add_argument("--layout", type=body_layout, default=None, metavar="paper10|full|FILE",
                        help=f"the body layout (docs/body.md): paper10, full (feet, hands, chest, head) or a "
                             f"layout file; {default_text}")


def check_names(args: argparse.Namespace) -> None:
    """``--names``' segments are the layout's in effect: ``--layout``'s (a layout file's own too),
    or a built-in layout's where it is not given (the subjects' layouts are then built-ins); FlagError
    naming the first segment the layout lacks and its segments."""
    chosen = getattr(args, "layout", None)
    try:
        names.check_segments(args.names, layout(args) if isinstance(chosen, str) else chosen)
    except ValueError as exc:
        raise FlagError(str(exc)) from None


def names_argv(mapping: dict[str, str] | None) -> list[str]:
    """The flags that give ``mapping`` to a child process (none for None)."""
    return [] if mapping is None else ["--names", ",".join(f"{sensor}={segment}" for sensor, segment in mapping.items())]


# ----------------------------------------------------------------------------- the body's layout

DEFAULT_LAYOUT = "full"
"""The layout of ``--layout`` when not given (``emulate``, ``up``, ``gateway slimevr``): the whole
body, 15 segments (``paper10``, the paper's 10, by ``--layout paper10``)."""


def add_layout(parser: argparse.ArgumentParser, help_text: str | None = None) -> None:
    """``--layout paper10|full|FILE``: the body the built-in generator moves, one device per
    segment, and the layout of the body the devices announce (``emulate``, ``up``; checked by
    :func:`layout`); ``help_text``: another command's use of it (a gateway's)."""
    parser.add_argument("--layout", default=None, metavar="paper10|full|FILE",
                        help=help_text or "the subjects' body layout (docs/body.md): the generator moves a device per "
                             f"segment of it, {DEFAULT_LAYOUT} (15 segments: pelvis, chest, head, arms, hands, legs "
                             "and feet; default), paper10 (the paper's 10: no chest, hands or feet) or a .toml/.json "
                             "layout file of segments it moves; a BVH file is read onto it (without it: paper10); "
                             "another motion file streams its own segments, which the layout must hold (the body of "
                             "its --height-m/--body: paper10's unless --layout says); "
                             "--height-m and --body size a body of it")


def layout(args: argparse.Namespace) -> Layout:
    """The layout of ``--layout``; FlagError naming a bad one. Not given: :data:`DEFAULT_LAYOUT` for
    a command that takes ``--layout`` and streams the generator or a gateway's trackers; ``paper10``
    for a motion file's subjects (their devices are the file's own segments) and a command without
    the flag (``gateway serial``)."""
    from limbstream import body
    value = getattr(args, "layout", None)
    if value is None:
        takes = hasattr(args, "layout") and getattr(args, "source", "generator") == "generator"
        return body.LAYOUTS[DEFAULT_LAYOUT] if takes else body.PAPER10
    try:
        return body.layout(value)
    except (OSError, ValueError) as exc:
        raise FlagError(f"--layout {exc}" if str(exc).startswith(str(value)) else f"--layout: {exc}") from None


def source_layout(args: argparse.Namespace) -> Layout | None:
    """The layout ``up`` and ``emulate`` read a motion file ``--source`` onto: ``--layout``'s when
    given and the source is BVH files (a ``.bvh`` file, or a folder whose motion files are all
    ``.bvh``): a joint maps to each of its segments, which the devices stream. None for other
    sources, which stream their own segments (:func:`check_source_layout`), and without it."""
    if getattr(args, "layout", None) is None:
        return None
    path = Path(args.source)
    kinds = {p.suffix.lower() for p in (path.iterdir() if path.is_dir() else [path])} & {".npz", ".bvh", ".csv", ".txt"}
    return layout(args) if kinds == {".bvh"} else None


def check_source_layout(args: argparse.Namespace, segments: tuple[str, ...], source: str) -> None:
    """A motion file's devices are its own segments: ``--layout``, when given, is the layout of
    the body they announce (``--height-m``, ``--body``) and must hold every one of ``segments``;
    FlagError naming those it has not."""
    if getattr(args, "layout", None) is None:
        return
    wanted = layout(args)
    missing = [s for s in segments if s not in wanted.segment_names]
    if missing:
        raise FlagError(f"--layout {wanted.name}: the source {source} moves segment{'s' * (len(missing) > 1)} "
                        f"{', '.join(missing)}, not in the layout (a motion file's devices are its own segments)")


def no_root_note(layouts) -> str | None:
    """The one line saying root translation is off, where one of ``layouts`` has no feet to track
    the root by (docs/body.md, "Root translation"); None where every one has them."""
    from limbstream.body.translation import has_feet
    footless = sorted({layout.name for layout in layouts if not has_feet(layout)})
    if not footless:
        return None
    names = " and ".join(footless)
    return f"root translation off: the {names} layout{'s have' if len(footless) > 1 else ' has'} no feet (--layout full has them)"


def layout_argv(args: argparse.Namespace) -> list[str]:
    """The flags that give ``--layout`` to a child process (a file as an absolute path)."""
    value = getattr(args, "layout", None)
    if value is None:
        return []
    from limbstream.body import LAYOUTS
    return ["--layout", value if value in LAYOUTS else str(Path(value).resolve())]


# ----------------------------------------------------------------------------- the wearer's dimensions

def add_body(parser: argparse.ArgumentParser, whose: str = "") -> None:
    """``--height-m H[,H...]`` and ``--body FILE[,FILE...]``: the subjects' dimensions, one value
    per subject in turn (``emulate``, ``up``; checked by :func:`bodies`); a gateway's, one for all
    its devices (``whose`` says whose, :func:`one_body`)."""
    group = parser.add_argument_group("the wearer's dimensions (docs/body.md; " + (
        whose or "default: the default adult of about 1.75 m, a BVH source's own skeleton") + ")")
    group.add_argument("--height-m", default=None, metavar="H[,H...]",
                       help="the subjects' heights, m, within [0.5, 2.5]: each bone by Winter's proportions; "
                            "several go to the subjects in turn")
    group.add_argument("--body", default=None, metavar="FILE[,FILE...]",
                       help="a .toml or .json file of the subjects' bone lengths, m (docs/body.md, 'Bodies'); "
                            "several go to the subjects in turn")


def bodies(args: argparse.Namespace) -> list[Body] | None:
    """The bodies of ``--height-m`` or ``--body`` (of the ``--layout``, :func:`layout`'s default), one
    per value; None when neither is given. FlagError naming the flag, the value and the bound, or a
    layout file that gives no height fraction for a bone when neither is given (its devices
    announce its default body, :func:`default_body`)."""
    from limbstream.body import Body
    height, files = getattr(args, "height_m", None), getattr(args, "body", None)
    if height is not None and files is not None:
        raise FlagError("--height-m and --body both give the subjects' dimensions: give one")
    lay = layout(args)
    if height is None and files is None:
        default_body(args)
    if height is not None:
        out = []
        for part in (p.strip() for p in height.split(",")):
            try:
                out.append(Body.from_height(lay, float(part)))
            except ValueError as exc:
                detail = str(exc) if part and "height" in str(exc) else f"a height in m, or several: H,H,..., got {part!r}"
                raise FlagError(f"--height-m: {detail}") from None
        return out
    if files is not None:
        out = []
        for part in (p.strip() for p in files.split(",")):
            try:
                out.append(Body.from_file(lay, part))
            except ValueError as exc:
                raise FlagError(f"--body {exc}") from None
        return out
    return None


def default_body(args: argparse.Namespace) -> Body | None:
    """The body devices of ``--layout`` announce when no ``--height-m`` or ``--body`` gives one:
    none for paper10 (the default adult), else the layout's default body (``Body.default``), which
    names the layout (a layout file's travels whole, ``wire.encode_body``). FlagError for a layout
    file that gives no height fraction for a bone (then ``--body`` gives its bones)."""
    from limbstream.body import PAPER10, Body
    lay = layout(args)
    if lay == PAPER10:
        return None
    try:
        return Body.default(lay)
    except ValueError as exc:
        raise FlagError(f"--layout {getattr(args, 'layout', lay.name)}: {exc}: its devices announce a body of it, "
                        f"give its bones with --body FILE") from None


def one_body(args: argparse.Namespace) -> Body | None:
    """The one body of a gateway's ``--height-m`` or ``--body`` (None: neither); FlagError for a
    bad one or for several (its devices are one wearer's)."""
    given = bodies(args)
    if given is not None and len(given) > 1:
        flag = "--height-m" if getattr(args, "height_m", None) is not None else "--body"
        raise FlagError(f"{flag}: one wearer's dimensions for the gateway's devices, got {len(given)}")
    return None if given is None else given[0]


def body_argv(args: argparse.Namespace) -> list[str]:
    """The flags that give ``--height-m`` or ``--body`` to a child process (files as absolute paths)."""
    if getattr(args, "height_m", None) is not None:
        return ["--height-m", args.height_m]
    if getattr(args, "body", None) is not None:
        return ["--body", ",".join(str(Path(p.strip()).resolve()) for p in args.body.split(","))]
    return []
