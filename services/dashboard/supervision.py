"""The parts' restart counts when ``limbstream up`` runs the dashboard.

``up`` keeps a JSON status file (its format: ``limbstream/cli/up.py``) and gives its path in
``LIMBSTREAM_UP_STATUS``. The file is read again when it changes; ``/health`` shows the parts
(``parts``: state, restarts, last exit), the page header their restarts, and Prometheus gets
``limbstream_up_restarts_total{part}``. Without the variable (not under ``up``) ``parts`` is null.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

from prometheus_client.core import CounterMetricFamily
from prometheus_client.registry import Collector
from pydantic import BaseModel, Field

from .models import Health

STATUS_ENV = "LIMBSTREAM_UP_STATUS"


class Part(BaseModel):
    state: str = Field(description="running, restarting (waiting for its back-off) or exited")
    restarts: int = Field(description="times ``limbstream up`` started it again")
    last_exit: str | None = Field(None, description="how it last ended, e.g. 'killed by SIGKILL'")


class HealthWithParts(Health):
    parts: dict[str, Part] | None = Field(None, description="the parts ``limbstream up`` runs (null without it)")


class UpStatus:
    """The status file of ``limbstream up`` (None: not run by it), parsed once per change."""

    def __init__(self, path: str | None = None):
        self.path = Path(path) if path else None
        self._seen: tuple[int, int, int] | None = None
        self._parts: dict[str, dict] | None = None

    @classmethod
    def from_env(cls) -> UpStatus:
        return cls(os.environ.get(STATUS_ENV) or None)

    def parts(self) -> dict[str, dict] | None:
        """{part: {state, restarts, last_exit}}; the last good reading if the file is unreadable."""
        if self.path is None:
            return None
        try:
            st = self.path.stat()
            if (st.st_ino, st.st_mtime_ns, st.st_size) != self._seen:
                parts = json.loads(self.path.read_text())["parts"]
                self._parts = {name: {k: p[k] for k in ("state", "restarts", "last_exit")}
                               for name, p in parts.items()}
                self._seen = (st.st_ino, st.st_mtime_ns, st.st_size)
        except (OSError, ValueError, KeyError, TypeError):
            pass
        return self._parts


class UpCollector(Collector):
    """``limbstream_up_restarts_total{part}`` on each scrape."""

    def __init__(self, status: UpStatus):
        self.status = status

    def collect(self):
        family = CounterMetricFamily("limbstream_up_restarts", "times limbstream up started a part again",
                                     labels=["part"])
        for name, part in (self.status.parts() or {}).items():
            family.add_metric([name], part["restarts"])
        yield family
