"""The one error type of the wire contract."""
from __future__ import annotations


class WireError(ValueError):
    """A payload or key that breaks the contract. ``reason`` is a short counter label."""

    def __init__(self, reason: str, message: str):
        super().__init__(f"{reason}: {message}")
        self.reason = reason
