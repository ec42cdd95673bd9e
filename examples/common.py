"""What the Zenoh examples share: their arguments, a subject and a router, and the config of a
client of that router (multicast scouting off: it connects to the router it is given only)."""
import sys

import zenoh


def client_config(router: str) -> zenoh.Config:
    """A client of ``router`` (e.g. ``tcp/127.0.0.1:7447``)."""
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", f'["{router}"]')
    config.insert_json5("scouting/multicast/enabled", "false")
    return config


def arguments() -> tuple[zenoh.Config, str]:
    """``SUBJECT ROUTER`` from the command line: (the client's config, the subject)."""
    subject, router = sys.argv[1], sys.argv[2]
    return client_config(router), subject
