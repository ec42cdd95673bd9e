"""Serve the dashboard with uvicorn until stopped (what ``limbstream dashboard`` starts)."""
from __future__ import annotations

from .settings import DashboardSettings


def run(settings: DashboardSettings, log_level: str = "warning") -> int:
    """Serve ``settings.host``:``settings.port``; a development token is generated if none is set.
    Returns the exit code once uvicorn stops (on SIGINT/SIGTERM)."""
    import uvicorn

    from .app import create_app

    settings, generated = settings.with_token()
    config = uvicorn.Config(create_app(settings), host=settings.host, port=settings.port, log_level=log_level,
                            ws_ping_interval=20, timeout_graceful_shutdown=3)
    server = uvicorn.Server(config)
    host = settings.host
    shown = "[::1]" if host == "::1" else ("127.0.0.1" if host in ("0.0.0.0", "") else host)
    print(f"dashboard: http://{shown}:{settings.port}/ (zenoh {settings.zenoh_mode} -> {settings.router})", flush=True)
    if generated:
        print(f"dashboard: development API token (set LIMBSTREAM_API_TOKEN to choose one): "
              f"{settings.api_token.get_secret_value()}", flush=True)
    elif settings.api_token is None:
        print("dashboard: device control disabled (production mode and no LIMBSTREAM_API_TOKEN)", flush=True)
    server.run()
    return 0
