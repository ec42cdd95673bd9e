"""Live pose streams: WebSocket ``/ws/pose/{subject}`` and server-sent events
``/sse/pose/{subject}``. Each client has a small queue; a slow client skips the oldest
frames (and is disconnected if one send blocks too long), it never stalls the others."""
from __future__ import annotations

import asyncio
import contextlib
from typing import Annotated
from urllib.parse import urlsplit

from fastapi import APIRouter, Query, Request, WebSocket, WebSocketDisconnect
from fastapi.responses import StreamingResponse

from limbstream import wire

from ..deps import LiveDep, SettingsDep, SubjectPath
from ..models import PoseKind

router = APIRouter(tags=["live"])

KEEPALIVE_S = 15.0
POLICY_VIOLATION = 1008


def origin_allowed(origin: str | None, host: str | None, allowed: list[str]) -> bool:
    """Same origin (or no Origin header: not a browser), or listed in the CORS origins."""
    if not origin:
        return True
    if origin in allowed or "*" in allowed:
        return True
    return bool(host) and urlsplit(origin).netloc == host


@router.websocket("/ws/pose/{subject}")
async def ws_pose(websocket: WebSocket, subject: str, live: LiveDep, settings: SettingsDep,
                  kind: PoseKind = "auto") -> None:
    """JSON pose frames of ``subject`` (:class:`~limbstream.services.dashboard.models.Pose`), as they come."""
    try:
        wire.check_chunk(subject, "subject")
    except ValueError:
        await websocket.close(POLICY_VIOLATION, "bad subject name")
        return
    if not origin_allowed(websocket.headers.get("origin"), websocket.headers.get("host"), settings.cors_origins):
        await websocket.close(POLICY_VIOLATION, "origin not allowed")
        return
    await websocket.accept()
    client = live.fanout.add(subject, kind, live.latest_pose(subject, kind))

    async def pump() -> None:
        while True:
            text = await client.queue.get()
            await asyncio.wait_for(websocket.send_text(text), settings.ws_send_timeout_s)
            client.sent += 1

    async def until_closed() -> None:
        while (await websocket.receive())["type"] != "websocket.disconnect":
            pass

    tasks = [asyncio.create_task(pump()), asyncio.create_task(until_closed())]
    try:
        await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in tasks:
            task.cancel()
        for task in tasks:
            with contextlib.suppress(asyncio.CancelledError, asyncio.TimeoutError, WebSocketDisconnect,
                                     RuntimeError, OSError):
                await task
        live.fanout.remove(client)
        with contextlib.suppress(RuntimeError, OSError, WebSocketDisconnect):
            await websocket.close()


@router.get("/sse/pose/{subject}", response_class=StreamingResponse,
            responses={200: {"content": {"text/event-stream": {}}, "description": "pose frames as SSE"}})
async def sse_pose(subject: SubjectPath, request: Request, live: LiveDep,
                   kind: PoseKind = "auto",
                   limit: Annotated[int | None, Query(ge=1, le=1_000_000,
                                                      description="end after this many frames")] = None):
    """Server-sent events: one ``data:`` line of pose JSON per frame."""
    client = live.fanout.add(subject, kind, live.latest_pose(subject, kind))

    async def events():
        sent = 0
        try:
            yield ": pose stream of " + subject + "\n\n"
            while limit is None or sent < limit:
                try:
                    text = await asyncio.wait_for(client.queue.get(), KEEPALIVE_S)
                except TimeoutError:
                    if await request.is_disconnected():
                        return
                    yield ": keep-alive\n\n"
                    continue
                yield f"data: {text}\n\n"
                sent += 1
                client.sent += 1
        finally:
            live.fanout.remove(client)

    return StreamingResponse(events(), media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})
