"""Operations: ``/health`` and Prometheus ``/metrics``."""
from __future__ import annotations

import time

from fastapi import APIRouter, Request, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from ..deps import LiveDep, SettingsDep, ViewsDep
from limbstream import wire

from ..models import Aggregator, Tunable
from ..supervision import HealthWithParts

router = APIRouter(tags=["ops"])


@router.get("/health", response_model=HealthWithParts,
            responses={503: {"model": HealthWithParts, "description": "starting"}})
async def health(request: Request, response: Response, live: LiveDep, settings: SettingsDep) -> dict:
    """200 once the Zenoh session is open, 503 while it is still connecting; ``parts``: restart
    counts of the parts when ``limbstream up`` runs them."""
    connected = request.app.state.bridge is not None
    response.status_code = 200 if connected else 503
    return {"status": "ok" if connected else "starting", "zenoh": connected,
            "subjects": len({e.subject for e in live.devices.values()} | set(live.poses)), "devices": len(live.devices),
            "uptime_s": round(time.monotonic() - request.app.state.started, 3),
            "control": settings.api_token is not None, "parts": request.app.state.up.parts()}


@router.get("/api/aggregators", response_model=list[Aggregator])
async def aggregators(views: ViewsDep) -> list[dict]:
    """Every aggregator heard from: its load, late ticks, backlog and losses."""
    return views.aggregator_views()


@router.get("/api/tunables", response_model=list[Tunable])
async def tunables() -> list[dict]:
    """The device settings ``PUT /api/devices/{subject}/{segment}/config`` accepts, with defaults
    and bounds (the page builds its control form from them)."""
    return [{"name": t.name, "type": t.type.__name__, "default": t.default, "low": t.low, "high": t.high,
             "unit": t.unit, "help": t.help} for t in wire.TUNABLES.values()]


@router.get("/metrics", response_class=Response,
            responses={200: {"content": {CONTENT_TYPE_LATEST: {}}, "description": "Prometheus text format"}})
async def metrics(request: Request) -> Response:
    """Prometheus exposition (per-device labels ``subject``, ``segment``)."""
    return Response(generate_latest(request.app.state.registry), media_type=CONTENT_TYPE_LATEST)
