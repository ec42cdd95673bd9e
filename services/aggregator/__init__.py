"""The aggregator service: SLERP reconstruction and full-body fusion of segment points."""
