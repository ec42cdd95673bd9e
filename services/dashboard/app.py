"""Assembles the dashboard app: settings, lifespan (Zenoh session), routers, the page at ``/``
(its files under ``/static``)."""
from __future__ import annotations

import asyncio
import threading
import time
from contextlib import asynccontextmanager

import zenoh
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import FileResponse, JSONResponse
from fastapi.staticfiles import StaticFiles

import limbstream
from limbstream import zconfig

from .deps import KnownQueryDep
from .metrics import build_registry
from .routes import devices, gateways, live, ops, subjects
from .settings import DashboardSettings
from .state import LiveState
from .supervision import UpCollector, UpStatus
from .views import Views
from .zenoh_io import open_bridge


@asynccontextmanager
async def lifespan(app: FastAPI):
    """Open the Zenoh session in the background (a client waits for its router; ``/health``
    answers 503 meanwhile), subscribe, and close everything on shutdown."""
    settings: DashboardSettings = app.state.settings
    state = LiveState(settings.history_seconds, settings.max_devices, settings.max_subjects, settings.ws_queue)
    app.state.live = state
    app.state.views = Views(state, settings.stale_after_s)
    app.state.registry = build_registry(state, app.state.views)
    app.state.up = UpStatus.from_env()
    app.state.registry.register(UpCollector(app.state.up))
    app.state.bridge = None
    app.state.started = time.monotonic()
    loop = asyncio.get_running_loop()
    inbox = state.attach(loop)
    closing = threading.Event()
    lock = threading.Lock()

    def connect() -> None:
        waiting = threading.Timer(zconfig.CONNECT_TIMEOUT_S, lambda: print(
            f"dashboard: no Zenoh router answered at {settings.router} within {zconfig.CONNECT_TIMEOUT_S:g} s; still "
            "waiting (/health answers 503 until then; set the endpoint with --connect or LIMBSTREAM_ROUTER)",
            flush=True))
        waiting.daemon = True
        if app.state.session is None:
            waiting.start()
        try:
            bridge = open_bridge(inbox, settings.zenoh_settings(), app.state.session)
        except zenoh.ZError as exc:
            print(f"dashboard: cannot open the Zenoh session: {exc}", flush=True)
            return
        finally:
            waiting.cancel()
        with lock:
            if closing.is_set():
                bridge.close()
                return
            app.state.bridge = bridge
            state.ask_layout = lambda subject: state.layouts.ask(bridge.session, subject)

    threading.Thread(target=connect, name="zenoh-connect", daemon=True).start()
    try:
        yield
    finally:
        with lock:
            closing.set()
            bridge, app.state.bridge = app.state.bridge, None
            state.ask_layout = None
        if bridge is not None:
            await asyncio.to_thread(bridge.close)


def create_app(settings: DashboardSettings | None = None, session: zenoh.Session | None = None) -> FastAPI:
    """The dashboard app.

    Parameters
    ----------
    settings : defaults to ``DashboardSettings()`` (environment); used as given (call
        :meth:`DashboardSettings.with_token` first for a development token).
    session : an open Zenoh session to use instead of opening one (left open on shutdown).
    """
    settings = settings or DashboardSettings()
    app = FastAPI(title="limbstream dashboard", version=limbstream.__version__, lifespan=lifespan,
                  description="Live device statistics, pose streams and device control of limbstream.")
    app.state.settings = settings
    app.state.session = session
    app.state.bridge = None
    if settings.cors_origins:
        app.add_middleware(CORSMiddleware, allow_origins=settings.cors_origins,
                           allow_methods=["GET", "PUT"], allow_headers=["Authorization", "Content-Type"])
    @app.exception_handler(RequestValidationError)
    async def invalid_request(_request: Request, exc: RequestValidationError) -> JSONResponse:
        """422 with where and what for each error, without echoing the input (a NaN in a body is
        not JSON and would break the answer)."""
        detail = [{k: e[k] for k in ("type", "loc", "msg") if k in e} for e in exc.errors()]
        return JSONResponse({"detail": detail}, status_code=422)

    for module in (ops, devices, subjects, gateways, live):
        app.include_router(module.router, dependencies=[KnownQueryDep])
    index = settings.static_dir / "index.html"

    @app.get("/", include_in_schema=False)
    async def page() -> FileResponse:
        return FileResponse(index, headers={"Cache-Control": "no-cache"})

    # Under /static, not at /: a mount at / would answer every unknown method on an API path.
    app.mount("/static", StaticFiles(directory=settings.static_dir), name="static")
    return app
