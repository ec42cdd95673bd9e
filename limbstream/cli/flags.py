"""The flags several commands share and the settings they make, written once: the device
tunables (:data:`limbstream.wire.TUNABLES`), the sensor model (:class:`limbstream.calibration.SensorModel`),
the Zenoh session (:class:`limbstream.zconfig.ZenohSettings`); and a command's one-line error.
The core library knows no argparse: its settings are built here from the parsed flags."""
from __future__ import annotations

import argparse
import os
import sys
from typing import TYPE_CHECKING

from limbstream import wire, zconfig

if TYPE_CHECKING:  # (calibration brings scipy: the commands without sensors start without it)
    from limbstream.calibration import SensorModel


def fail(prog: str, message: str) -> int:
    """Print ``PROG: error: MESSAGE`` on stderr; the exit status 2 of a bad flag."""
    print(f"{prog}: error: {message}", file=sys.stderr)
    return 2


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


def sensor_model(args: argparse.Namespace) -> SensorModel:
    """The SensorModel of the flags (ValueError naming a bad one)."""
    from limbstream.calibration import SensorModel
    return SensorModel(args.mounting_deg, args.heading_deg, args.yaw_drift_dps, args.sensor_seed)


def sensor_model_argv(model: SensorModel) -> list[str]:
    """The flags that give ``model`` (for a child process)."""
    return ["--mounting-deg", f"{model.mounting_deg:g}", "--heading-deg", f"{model.heading_deg:g}",
            "--yaw-drift-dps", f"{model.yaw_drift_dps:g}", "--sensor-seed", str(model.seed)]


# ----------------------------------------------------------------------------- zenoh

def add_zenoh(parser: argparse.ArgumentParser, mode: str = "client") -> None:
    """The shared ``--connect/--listen/--mode`` flags (router default from $LIMBSTREAM_ROUTER)."""
    group = parser.add_argument_group("zenoh")
    default = os.environ.get(zconfig.ROUTER_ENV, zconfig.DEFAULT_ROUTER if mode != "router" else "")
    group.add_argument("--connect", default=default,
                       help=f"endpoint(s) to connect to, comma-separated (env {zconfig.ROUTER_ENV}; "
                            f"default {default or 'none'})")
    group.add_argument("--listen", default="", help="endpoint(s) to listen on, comma-separated")
    group.add_argument("--mode", default=mode, choices=("client", "peer", "router"), help=f"zenoh mode (default {mode})")
    group.add_argument("--zenoh-config", default=os.environ.get(zconfig.CONFIG_ENV, ""),
                       help=f"JSON file of extra zenoh settings (key -> value), e.g. TLS/auth (env {zconfig.CONFIG_ENV})")


def zenoh_settings(args: argparse.Namespace) -> zconfig.ZenohSettings:
    """ZenohSettings from the flags of :func:`add_zenoh` (SystemExit naming a bad config file)."""
    try:
        return zconfig.settings(args.mode, args.connect, args.listen, args.zenoh_config)
    except ValueError as exc:
        raise SystemExit(str(exc)) from None
