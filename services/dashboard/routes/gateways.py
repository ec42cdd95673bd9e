"""``/api/gateways``: the sensors of every reachable gateway, and their assignment to devices."""
from __future__ import annotations

import asyncio
from typing import Annotated

from fastapi import APIRouter, HTTPException, Path, Request

from limbstream import wire

from ..deps import CHUNK, SettingsDep, TokenDep
from ..models import AssignRequest, Gateway
from ..zenoh_io import ConfigError, query_assign, query_gateways

router = APIRouter(prefix="/api/gateways", tags=["gateways"])

GatewayPath = Annotated[str, Path(pattern=CHUNK, max_length=128, description="gateway name", examples=["slimevr"])]


def _session(request: Request):
    bridge = request.app.state.bridge
    if bridge is None:
        raise HTTPException(503, "not connected to Zenoh yet")
    return bridge.session


@router.get("", response_model=list[Gateway], responses={503: {"description": "not connected to Zenoh yet"}})
async def list_gateways(request: Request, settings: SettingsDep) -> list[dict]:
    """Every gateway that answers within the config timeout, with each sensor it has heard of:
    the device it feeds, or why none."""
    gateways = await asyncio.to_thread(query_gateways, _session(request), settings.config_timeout_s)
    return [g | {"segments": list(wire.SEGMENTS)} for g in gateways]


@router.post("/{gateway}/assign", response_model=Gateway, dependencies=[TokenDep],
             responses={400: {"description": "the body is not decodable JSON"}, 401: {"description": "no bearer token"},
                        403: {"description": "bad token or control disabled"},
                        404: {"description": "no gateway of that name answered"},
                        409: {"description": "refused: the reason (an unknown sensor, a device fed by another "
                                              "sensor, ...)"},
                        502: {"description": "the gateway answered with something else than its sensors"},
                        503: {"description": "not connected to Zenoh yet"}})
async def assign(gateway: GatewayPath, body: AssignRequest, request: Request, settings: SettingsDep) -> dict:
    """Move a sensor to the device ``subject/segment`` (subject null: the gateway's), or to
    none (segment null). The device it fed ends its stream; the new one starts a stream at the
    sensor's next rotation. Answers the gateway's sensors after the change."""
    assignment = wire.Assignment(body.tracker, body.sensor, body.subject, body.segment)
    try:
        listing = await asyncio.to_thread(query_assign, _session(request), gateway, assignment,
                                          settings.config_timeout_s)
        return listing | {"segments": list(wire.SEGMENTS)}
    except ConfigError as exc:
        raise HTTPException(exc.status, exc.message) from None
