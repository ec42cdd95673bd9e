"""``/api/devices``: latest stats, history and configuration of devices."""
from __future__ import annotations

import asyncio
from typing import Annotated

from fastapi import APIRouter, HTTPException, Query, Request

from limbstream import wire

from ..deps import LiveDep, SegmentPath, SettingsDep, SubjectPath, TokenDep
from ..models import ConfigUpdate, DeviceConfig, DeviceHistory, DeviceStats
from ..zenoh_io import ConfigError, query_config

router = APIRouter(prefix="/api/devices", tags=["devices"])

NOT_FOUND = {404: {"description": "unknown device"}}


def _known(live, subject: str, segment: str) -> str:
    did = wire.device_id(subject, segment)
    if did not in live.devices:
        raise HTTPException(404, f"unknown device {did!r}")
    return did


@router.get("", response_model=list[DeviceStats])
async def list_devices(live: LiveDep, subject: Annotated[str | None, Query(
        pattern=wire.CHUNK_PATTERN, max_length=128, description="only this subject's devices")] = None) -> list[dict]:
    """Every device seen (stats or liveliness), sorted by id; ``subject``: only that subject's."""
    return live.device_views(subject)


@router.get("/{subject}/{segment}", response_model=DeviceStats, responses=NOT_FOUND)
async def get_device(subject: SubjectPath, segment: SegmentPath, live: LiveDep) -> dict:
    """One device; its id is ``<subject>/<segment>``."""
    return live.device_view(_known(live, subject, segment))


@router.get("/{subject}/{segment}/history", response_model=DeviceHistory, responses=NOT_FOUND)
async def device_history(subject: SubjectPath, segment: SegmentPath, live: LiveDep, settings: SettingsDep,
                   seconds: Annotated[float, Query(gt=0, le=86_400, description="window, s")] = 300) -> dict:
    """Time series for the charts, the last ``seconds`` (at most the kept history)."""
    did = _known(live, subject, segment)
    return {"device": did} | live.history(did, min(seconds, settings.history_seconds))


@router.put("/{subject}/{segment}/config", response_model=DeviceConfig, dependencies=[TokenDep],
            responses={400: {"description": "the body is not decodable JSON"}, 401: {"description": "no bearer token"}, 403: {"description": "bad token or control disabled"},
                       **NOT_FOUND, 504: {"description": "the device did not confirm in time"},
                       502: {"description": "the device answered with something else than a config"}})
async def put_config(subject: SubjectPath, segment: SegmentPath, body: ConfigUpdate, request: Request,
                     live: LiveDep, settings: SettingsDep) -> dict:
    """Send new settings (some of the device tunables) to a device over Zenoh and answer with
    the status the device confirms (fields left out keep the device's current value)."""
    _known(live, subject, segment)
    bridge = request.app.state.bridge
    if bridge is None:
        raise HTTPException(503, "not connected to Zenoh yet")
    try:
        status = await asyncio.to_thread(query_config, bridge.session, subject, segment, body.update(),
                                         settings.config_timeout_s)
    except ConfigError as exc:
        raise HTTPException(exc.status, exc.message) from None
    return status.as_dict()
