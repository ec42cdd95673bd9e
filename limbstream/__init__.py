"""limbstream: live full-body motion capture over Zenoh from IMUs that send only segment points."""

__version__ = "0.1.0"
