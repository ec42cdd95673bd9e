"""Print a subject's live pose frames with plain Zenoh: the left wrist's position, 5 frames.

    python examples/live_frames.py s01 tcp/127.0.0.1:7447
"""
import zenoh
from common import arguments

from limbstream import wire


def main(config: zenoh.Config, subject: str, count: int = 5) -> None:
    with zenoh.open(config) as session:
        frames = session.declare_subscriber(wire.pose_key(subject), zenoh.handlers.FifoChannel(256))
        shown = 0
        while shown < count:
            frame = wire.decode_pose(frames.recv().payload.to_bytes())
            if frame.kind == wire.KIND_LIVE:
                x, y, z = frame.joints[wire.JOINTS.index("l_wrist")]
                print(f"{subject} t={frame.t_us / 1e6:.3f} s  l_wrist x={x:+.3f} y={y:+.3f} z={z:+.3f} m")
                shown += 1


if __name__ == "__main__":
    main(*arguments())
