"""Ask every device of a subject for its settings and counters (its config queryable).

    python examples/device_settings.py s01 tcp/127.0.0.1:7447
"""
import sys

import zenoh

from limbstream import wire

subject, router = sys.argv[1], sys.argv[2]
config = zenoh.Config()
config.insert_json5("mode", '"client"')
config.insert_json5("connect/endpoints", f'["{router}"]')
config.insert_json5("scouting/multicast/enabled", "false")
with zenoh.open(config) as session:
    for reply in session.get(wire.device_selector("config", subject), timeout=5.0):
        if reply.ok is None:
            continue
        status = wire.decode_status(reply.ok.payload.to_bytes())
        c = status.config
        print(f"{status.device}: threshold {c.threshold:g}, max_len {c.max_len}, live bound {c.live_bound_deg:g} deg, "
              f"{status.points} points / {status.samples} samples, rest pose {status.rest_pose}")
