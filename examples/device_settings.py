"""Ask every device of a subject for its settings and counters (its config queryable).

    python examples/device_settings.py s01 tcp/127.0.0.1:7447
"""
import zenoh
from common import arguments

from limbstream import wire


def main(config: zenoh.Config, subject: str) -> None:
    with zenoh.open(config) as session:
        for reply in session.get(wire.device_selector("config", subject), timeout=5.0):
            if reply.ok is None:
                continue
            status = wire.decode_status(reply.ok.payload.to_bytes())
            c = status.config
            print(f"{status.device}: threshold {c.threshold:g}, max_len {c.max_len}, live bound "
                  f"{c.live_bound_deg:g} deg, {status.points} points / {status.samples} samples, "
                  f"rest pose {status.rest_pose}")


if __name__ == "__main__":
    main(*arguments())
