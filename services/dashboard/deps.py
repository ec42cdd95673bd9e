"""Dependencies declared once (``Annotated``) and used by the routes."""
from __future__ import annotations

import secrets
from typing import Annotated

from fastapi import Depends, HTTPException, Path
from fastapi.exceptions import RequestValidationError, WebSocketRequestValidationError
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.requests import HTTPConnection

from limbstream import wire

from .settings import DashboardSettings
from .state import LiveState

CHUNK = wire.CHUNK_PATTERN


async def _settings(conn: HTTPConnection) -> DashboardSettings:
    return conn.app.state.settings


async def _live(conn: HTTPConnection) -> LiveState:
    return conn.app.state.live


SettingsDep = Annotated[DashboardSettings, Depends(_settings)]
LiveDep = Annotated[LiveState, Depends(_live)]
SubjectPath = Annotated[str, Path(pattern=CHUNK, max_length=128, description="subject name", examples=["s01"])]
SegmentPath = Annotated[str, Path(pattern=CHUNK, max_length=128, description="segment name", examples=["hip"])]

_bearer = HTTPBearer(auto_error=False, description="LIMBSTREAM_API_TOKEN")


async def _require_token(settings: SettingsDep,
                   credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]) -> None:
    if settings.api_token is None:
        raise HTTPException(403, "device control is disabled: no API token is configured "
                                 "(set LIMBSTREAM_API_TOKEN)")
    if credentials is None:
        raise HTTPException(401, "missing bearer token (header 'Authorization: Bearer <token>')",
                            headers={"WWW-Authenticate": "Bearer"})
    expected = settings.api_token.get_secret_value().encode()
    if not secrets.compare_digest(credentials.credentials.encode(), expected):
        raise HTTPException(403, "invalid token")


TokenDep = Depends(_require_token)


def _declared_query(dependant) -> set[str]:
    """The query parameters a route (or dependency) declares, with those of its dependencies."""
    names = {f.alias for f in dependant.query_params}
    for sub in dependant.dependencies:
        names |= _declared_query(sub)
    return names


async def _only_declared_query(conn: HTTPConnection) -> None:
    """Refuse (422; a WebSocket: close code 1008) a query parameter the route does not declare,
    naming it and the ones it takes: a misspelt filter never answers as if it were not given."""
    dependant = getattr(conn.scope.get("route"), "dependant", None)
    declared = _declared_query(dependant) if dependant is not None else set()
    unknown = sorted(set(conn.query_params) - declared)
    if unknown:
        takes = f"it takes {', '.join(sorted(declared))}" if declared else "it takes none"
        errors = [{"type": "extra_forbidden", "loc": ("query", name), "msg": f"unknown query parameter ({takes})"}
                  for name in unknown]
        raise (WebSocketRequestValidationError if conn.scope["type"] == "websocket" else RequestValidationError)(errors)


KnownQueryDep = Depends(_only_declared_query)
"""On every API router: only the query parameters a route declares."""
