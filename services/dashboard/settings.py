"""Dashboard settings: one pydantic-settings object, environment prefix ``LIMBSTREAM_``.

Secrets have no defaults. In ``development`` mode a missing API token is generated at start
(and printed by ``limbstream dashboard``); in ``production`` mode a missing token disables
the control endpoints (403 with a message naming ``LIMBSTREAM_API_TOKEN``).
"""
from __future__ import annotations

import secrets
import importlib.resources
from pathlib import Path
from typing import Literal

from pydantic import Field, SecretStr, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from limbstream import zconfig

DASHBOARD_DIR = Path(str(importlib.resources.files("limbstream.dashboard")))
"""The web page (index.html, app.js, style.css, vendor/) served at ``/``: the package data of
limbstream.dashboard (the repository's dashboard/ folder)."""


class DashboardSettings(BaseSettings):
    """Everything the dashboard service reads from its environment.

    Attributes
    ----------
    mode : "development" | "production"
        Development generates an API token when none is set; production never does.
    api_token : SecretStr or None
        Bearer token for the control endpoints (``LIMBSTREAM_API_TOKEN``).
    router : str
        Zenoh endpoint(s) to connect to, comma-separated (``LIMBSTREAM_ROUTER``).
    zenoh_mode : "client" | "peer"
    zenoh_config : str
        JSON file of extra zenoh settings (TLS, auth), as in :mod:`limbstream.zconfig`.
    host, port : where uvicorn binds (``limbstream dashboard --http HOST:PORT``).
    cors_origins : list of str
        Extra origins allowed by CORS; empty = same origin only.
    history_seconds : int
        Seconds of per-device history kept (one point per stats message, ~1 Hz).
    max_devices, max_subjects : int
        Bounds on tracked devices/subjects; stats for more are counted and dropped.
    stale_after_s : float
        A device whose last stats are older than this is reported ``stale``.
    config_timeout_s : float
        How long ``PUT /api/devices/{id}/config`` waits for the device to confirm.
    ws_queue : int
        Frames queued per WebSocket/SSE client; a slow client skips the oldest.
    ws_send_timeout_s : float
        A client whose single send blocks longer than this is disconnected.
    """

    model_config = SettingsConfigDict(env_prefix="LIMBSTREAM_", extra="ignore")

    mode: Literal["development", "production"] = "development"
    api_token: SecretStr | None = None
    router: str = zconfig.DEFAULT_ROUTER
    zenoh_mode: Literal["client", "peer"] = "client"
    zenoh_config: str = ""
    host: str = "127.0.0.1"
    port: int = Field(8000, ge=0, le=65535)
    cors_origins: list[str] = Field(default_factory=list)
    history_seconds: int = Field(900, ge=10, le=86_400)
    max_devices: int = Field(10_000, ge=1)
    max_subjects: int = Field(1_000, ge=1)
    stale_after_s: float = Field(5.0, gt=0)
    config_timeout_s: float = Field(2.0, gt=0, le=60)
    ws_queue: int = Field(16, ge=1, le=1024)
    ws_send_timeout_s: float = Field(5.0, gt=0)
    static_dir: Path = DASHBOARD_DIR

    @field_validator("api_token")
    @classmethod
    def _no_blank_token(cls, value: SecretStr | None) -> SecretStr | None:
        if value is not None and not value.get_secret_value().strip():
            return None
        return value

    def with_token(self) -> tuple[DashboardSettings, bool]:
        """These settings, with a generated token in development mode if none is set.

        Returns
        -------
        settings, generated : the settings to use and whether the token was generated.
        """
        if self.api_token is None and self.mode == "development":
            token = SecretStr(secrets.token_urlsafe(24))
            return self.model_copy(update={"api_token": token}), True
        return self, False

    def zenoh_settings(self) -> zconfig.ZenohSettings:
        """The Zenoh session settings: a client waits for its router however long it takes
        (``/health`` answers 503 meanwhile). SystemExit naming a bad ``zenoh_config`` file."""
        try:
            extra = zconfig.read_extra(self.zenoh_config) if self.zenoh_config else {}
        except ValueError as exc:
            raise SystemExit(f"--zenoh-config {exc}") from None
        return zconfig.ZenohSettings(mode=self.zenoh_mode, connect=zconfig.split_list(self.router), extra=extra)
