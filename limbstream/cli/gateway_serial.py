"""``limbstream gateway serial``: one device on a serial link (USB CDC, a UART, or the device
firmware under QEMU on ``tcp:HOST:PORT``) bridged to Zenoh as ``<subject>/<segment>``
(:mod:`limbstream.services.gateway.serial_gateway`; the link: docs/protocol.md, "Serial link")."""
from __future__ import annotations

import argparse
import logging
import sys

from limbstream import wire, zconfig
from limbstream.cli import flags
from limbstream.device.feeds import GeneratorFeed, LoopFeed
from limbstream.device.host import HostSettings
from limbstream.signals import stop_on_signals
from limbstream.sources import MotionFileError, load


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", required=True,
                        help="the link: a serial device (/dev/ttyACM0, /dev/ttyUSB0) or tcp:HOST:PORT")
    parser.add_argument("--subject", required=True, help="the device's subject (a key chunk, e.g. s01)")
    parser.add_argument("--segment", required=True, help="the device's segment (a key chunk, e.g. pelvis)")
    parser.add_argument("--source", default=None,
                        help="feed the device this motion, standing in for its IMU: 'generator' or a motion file "
                             "(its truth tap is published); default: the device samples its own IMU")
    parser.add_argument("--once", action="store_true", help="play a file source once, then end the stream and idle")
    parser.add_argument("--rate", type=float, default=wire.DEVICE_RATE_HZ,
                        help=f"sample rate fed, Hz (default {wire.DEVICE_RATE_HZ:g})")
    parser.add_argument("--speed", type=float, default=1.0, help="time scale of the feeding (default 1 = real time)")
    parser.add_argument("--seed", type=int, default=1, help="generator seed (default 1: subject s01's)")
    parser.add_argument("--duration", type=float, default=None, help="stop after this many seconds of device time")
    flags.add_device_config(parser)  # the device tunables, given to the device at every (re)start
    parser.add_argument("--no-truth", dest="truth", action="store_false", help="do not publish the truth tap")
    parser.add_argument("--raw-batch", type=int, default=25, help="samples per truth-tap message (default 25)")
    parser.add_argument("--cache", type=int, default=512, help="segment points kept for recovery (default 512)")
    parser.add_argument("--link-timeout", type=float, default=10.0,
                        help="seconds to keep trying to open the link at start (default 10)")
    flags.add_body(parser, "of the device's wearer; default: a --source BVH file's own skeleton, else the default "
                           "adult of about 1.75 m")
    parser.add_argument("--silence-s", type=float, default=10.0,
                        help="a device not heard from for this long (it sends a heartbeat every second) is offline: "
                             "its link is reopened as a new stream (default 10)")
    parser.add_argument("-v", "--verbose", action="store_true")
    flags.add_zenoh(parser)


def feeding(args: argparse.Namespace):
    """The Feeding of --source (None without), its rest pose; SystemExit naming a bad flag."""
    from limbstream.services.gateway.serial_gateway import Feeding
    if args.source is None:
        return None, wire.DEFAULT_REST_POSE
    try:
        feed = (GeneratorFeed(seed=args.seed, fs=args.rate) if args.source == "generator"
                else LoopFeed(load(args.source)[0], args.rate, once=args.once))
    except (MotionFileError, ValueError) as exc:
        raise SystemExit(f"limbstream gateway serial: error: {exc}") from None
    if args.segment not in feed.segments:
        raise SystemExit(f"limbstream gateway serial: error: --segment {args.segment!r} is not in the source's "
                         f"segments {list(feed.segments)}")
    return Feeding(feed, list(feed.segments).index(args.segment)), feed.rest_pose


def run(args: argparse.Namespace) -> int:
    from limbstream.services.gateway import serial_gateway
    from limbstream.services.gateway.serial_port import SerialLink
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(message)s")
    for ok, message in ((args.rate > 0, f"--rate must be > 0, got {args.rate}"),
                        (args.speed > 0, f"--speed must be > 0, got {args.speed}"),
                        (args.silence_s > 1, f"--silence-s must be > 1 (the heartbeat's period), got {args.silence_s}"),
                        (1 <= args.raw_batch <= wire.MAX_RAW_BATCH, f"--raw-batch must be in 1..{wire.MAX_RAW_BATCH}")):
        if not ok:
            raise SystemExit(f"limbstream gateway serial: error: {message}")
    try:
        wire.check_chunk(args.subject, "subject"), wire.check_chunk(args.segment, "segment")
    except ValueError as exc:
        raise SystemExit(f"limbstream gateway serial: error: {exc}") from None
    body = flags.one_body(args)  # FlagError: one line, exit status 2
    feed, rest_pose = feeding(args)
    body = body or (None if feed is None else feed.feed.body)
    stop = stop_on_signals()
    session = zconfig.open_session(flags.session_settings(args, "limbstream gateway serial"), stop)
    if session is None:
        return 0
    with session:
        host = serial_gateway.serial_host(session, HostSettings(
            fs=args.rate, config=flags.device_config(args), truth=args.truth and feed is not None,
            raw_batch=args.raw_batch, cache=args.cache))
        host.declare()
        links: list[SerialLink] = []  # a longer wait for the first link, then the reconnects' short one

        def connect() -> SerialLink:
            links.append(SerialLink(args.port, args.link_timeout if not links else 0.5, stop))
            return links[-1]

        gateway = serial_gateway.SerialGateway(host, connect, args.subject, args.segment, feed, rest_pose=rest_pose,
                                               silence_s=args.silence_s, body=body)
        print(f"limbstream gateway serial: connected; opening the link {args.port} (up to {args.link_timeout:g} s)",
              file=sys.stderr, flush=True)
        if not gateway.open():
            gateway.close()
            host.close()
            if stop.is_set():
                return 0
            raise SystemExit(f"limbstream gateway serial: error: no device on {args.port}")
        print(f"gateway serial: {gateway.id} on {args.port}, stream {gateway.stream}"
              + ("" if feed is None else f", fed {args.source} at {args.rate:g} Hz x{args.speed:g}"), flush=True)
        try:
            serial_gateway.run(host, [gateway], stop, args.speed, args.duration)
        finally:
            print(f"gateway serial: {gateway.summary()}", flush=True)
            gateway.close()
            host.close()
    return 0
