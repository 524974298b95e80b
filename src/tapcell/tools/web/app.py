"""`tapcell web`: the tap store in the browser, read-only.

Pages: the fleet (every printer's last probe and health, with a change test), a printer (its
taps filtered by status and cause, the mesh heat map and the difference of two meshes, the bed
map of rejected taps with faulty_region suggestions) and a tap (force against time and Z, the
fitted lines, both Z values, the cause). `/events` streams server-sent events when a monitor
writes a tap or a mesh, so open pages update without a reload. Everything the pages load is
served from here: nothing comes from the internet.

Bad input (an unknown printer, a hostile query string, a mesh pair on different grids) gets a
page saying what was wrong with status 400 or 404; an unexpected error gets a 500 page and a
traceback in the server's log only.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import re
import sys
import time
from pathlib import Path

from jinja2 import Environment, FileSystemLoader, select_autoescape
from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.responses import HTMLResponse, JSONResponse, StreamingResponse
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from tapcell.store import Store, StoreError, health
from tapcell.store.database import FLEET_WINDOW_TAPS
from tapcell.tools.web import views

HERE = Path(__file__).resolve().parent
STATIC = HERE / "static"
VENDOR_FILES = ("uPlot.iife.min.js", "uPlot.min.css")
EVENT_POLL_S = 0.25
KEEPALIVE_S = 15.0
TAP_PAGE_ROWS = 200
STATUSES = ("all", "valid", "rejected")
CAUSE_PATTERN = re.compile(r"[A-Za-z0-9_]{1,100}")
MAX_ID = 2**63 - 1  # the databases' largest integer: a larger id in a URL is no tap
log = logging.getLogger("tapcell.web")


class BadRequest(HTTPException):
    def __init__(self, detail: str):
        super().__init__(400, detail)


def _int_param(request: Request, name: str, minimum: int = 1) -> int | None:
    value = request.query_params.get(name)
    if value is None or value == "":
        return None
    if not value.isascii() or not value.isdigit() or len(value) > 18 or int(value) < minimum:
        raise BadRequest(f"{name}: {value[:40]!r} is not a whole number ≥ {minimum}")
    return int(value)


def _choice(request: Request, name: str, allowed: tuple[str, ...]) -> str:
    value = request.query_params.get(name) or allowed[0]
    if value not in allowed:
        raise BadRequest(f"{name}: {value[:40]!r} is not one of {', '.join(allowed)}")
    return value


def _tap_filter(request: Request) -> tuple[str, str]:
    """The tap list's filter from the query string: (status, cause code)."""
    status = _choice(request, "status", STATUSES)
    cause = request.query_params.get("cause") or ""
    if cause and not CAUSE_PATTERN.fullmatch(cause):
        raise BadRequest(f"cause: {cause[:40]!r} is not an error code (letters, digits and _)")
    return status, cause


class Web:
    """The pages over one store."""

    def __init__(self, store: Store):
        self.store = store
        self.templates = Environment(loader=FileSystemLoader(HERE / "templates"),
                                     autoescape=select_autoescape(["html"]))
        self.templates.filters["num"] = _num
        self.templates.filters["when"] = _when

    def page(self, name: str, status_code: int = 200, **context) -> HTMLResponse:
        context.setdefault("thresholds", {"t": health.TREND_T_THRESHOLD, "recent": health.RECENT_TAPS,
                                          "baseline": health.BASELINE_TAPS})
        return HTMLResponse(self.templates.get_template(name).render(**context), status_code=status_code)

    def _printer(self, name: str) -> dict:
        printer = self.store.printer(name)
        if printer is None:
            raise HTTPException(404, f"no printer named {name[:100]!r} in this store")
        return printer

    # -- pages -----------------------------------------------------------------------------------
    def fleet(self, request: Request) -> HTMLResponse:
        rows = self.store.fleet()
        return self.page("fleet.html", fleet=rows, fleet_json=_fleet_json(rows), window=FLEET_WINDOW_TAPS)

    def printer(self, request: Request) -> HTMLResponse:
        printer = self._printer(request.path_params["name"])
        status, cause = _tap_filter(request)
        mesh_id, base_id = _int_param(request, "mesh"), _int_param(request, "base")
        taps = self.store.taps(printer["id"], status=status, cause=cause, limit=TAP_PAGE_ROWS)
        wanted_ids = tuple(wanted for wanted in (mesh_id, base_id) if wanted is not None)
        meshes = self.store.meshes(printer["id"], ids=wanted_ids)
        by_id = {mesh["id"]: mesh for mesh in meshes}
        for wanted in (mesh_id, base_id):
            if wanted is not None and wanted not in by_id:
                raise HTTPException(404, f"no mesh {wanted} for printer {printer['name']!r}")
        shown = by_id[mesh_id] if mesh_id else (meshes[0] if meshes else None)
        mesh = None
        mesh_problem = ""
        if shown is not None:
            if base_id is not None:
                try:
                    mesh = views.mesh_difference(shown, by_id[base_id])
                except views.MeshMismatch as exc:
                    mesh_problem = str(exc)
                    mesh = views.mesh_view(shown)
            else:
                mesh = views.mesh_view(shown)
        spots = self.store.bed_spots(printer["id"])
        return self.page("printer.html", printer=printer, taps=taps, status=status, cause=cause,
                         statuses=STATUSES, causes=self.store.causes(printer["id"]), meshes=meshes,
                         mesh=mesh, mesh_json=mesh, mesh_problem=mesh_problem, mesh_id=shown["id"] if shown else None,
                         base_id=base_id, bed=views.bed_map(spots), latest_id=max((t["id"] for t in taps), default=0),
                         latest_mesh_id=max((m["id"] for m in meshes), default=0))

    def tap(self, request: Request) -> HTMLResponse:
        printer = self._printer(request.path_params["name"])
        tap_id = request.path_params["tap_id"]
        row = self.store.tap(printer["id"], tap_id) if tap_id <= MAX_ID else None
        if row is None:
            raise HTTPException(404, f"no tap {tap_id} for printer {printer['name']!r}")
        return self.page("tap.html", printer=printer, tap=row, plot=views.tap_plot(row))

    # -- data for live updates -------------------------------------------------------------------
    def fleet_json(self, request: Request) -> JSONResponse:
        return JSONResponse(_fleet_json(self.store.fleet()))

    def taps_json(self, request: Request) -> JSONResponse:
        printer = self._printer(request.path_params["name"])
        status, cause = _tap_filter(request)
        after = _int_param(request, "after", minimum=0) or 0
        rows = [row for row in self.store.taps(printer["id"], status=status, cause=cause, limit=TAP_PAGE_ROWS)
                if row["id"] > after]
        return JSONResponse([_tap_row_json(row) for row in rows])

    def meshes_json(self, request: Request) -> JSONResponse:
        """The printer's latest meshes, newest first: id, profile, time (for the live notice)."""
        printer = self._printer(request.path_params["name"])
        return JSONResponse([{key: mesh[key] for key in ("id", "profile", "recorded_s")}
                             for mesh in self.store.meshes(printer["id"], limit=10)])

    async def events(self, request: Request) -> StreamingResponse:
        """Server-sent events: `change` with the newest {tap, mesh} ids when the store grows."""
        async def stream():
            last = await run_in_threadpool(self.store.latest_ids)
            yield f"event: hello\ndata: {json.dumps(last)}\n\n"
            quiet_since = time.monotonic()
            while not await request.is_disconnected():
                await asyncio.sleep(EVENT_POLL_S)
                try:
                    now = await run_in_threadpool(self.store.latest_ids)
                except Exception:  # the database went away: say so once, keep the page, try again
                    log.exception("reading the store for live updates")
                    yield "event: problem\ndata: \"the store cannot be read now\"\n\n"
                    await asyncio.sleep(1.0)
                    continue
                if now != last:
                    last = now
                    quiet_since = time.monotonic()
                    yield f"event: change\ndata: {json.dumps(now)}\n\n"
                elif time.monotonic() - quiet_since > KEEPALIVE_S:
                    quiet_since = time.monotonic()
                    yield ": keep-alive\n\n"

        return StreamingResponse(stream(), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"})

    # -- errors ----------------------------------------------------------------------------------
    async def http_error(self, request: Request, exc: HTTPException):
        if request.url.path.startswith("/api/"):
            return JSONResponse({"error": exc.detail}, status_code=exc.status_code)
        return self.page("error.html", status_code=exc.status_code, code=exc.status_code, message=exc.detail)

    async def server_error(self, request: Request, exc: Exception):
        log.error("error serving %s", request.url.path, exc_info=exc)
        message = "the page could not be made; the server's log says why"
        if isinstance(exc, StoreError):
            message = str(exc)
        return self.page("error.html", status_code=500, code=500, message=message)


def _tap_row_json(row: dict) -> dict:
    return {key: row[key] for key in ("id", "recorded_s", "x_mm", "y_mm", "printer_z_mm", "tapcell_z_mm",
                                      "printer_valid", "tapcell_valid", "quality", "cause")}


def _fleet_json(rows: list[dict]) -> list[dict]:
    return [{key: row[key] for key in ("name", "id", "taps", "window", "repeatability_um", "stiffness_g_um",
                                       "noise_sigma_g", "rejection_rate", "trends", "flagged", "series")}
            | {"last": None if row["last"] is None else _tap_row_json(row["last"])} for row in rows]


def _num(value, spec: str = ".4f", default: str = "–") -> str:
    if value is None:
        return default
    try:
        return format(value, spec)
    except (TypeError, ValueError):
        return str(value)


def _when(seconds) -> str:
    return "–" if seconds is None else time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(seconds))


def missing_assets() -> list[str]:
    return [name for name in VENDOR_FILES if not (STATIC / "vendor" / name).exists()]


def create_app(store: Store) -> Starlette:
    web = Web(store)
    routes = [
        Route("/", web.fleet),
        Route("/printer/{name}", web.printer),
        Route("/printer/{name}/tap/{tap_id:int}", web.tap),
        Route("/api/fleet", web.fleet_json),
        Route("/api/printer/{name}/taps", web.taps_json),
        Route("/api/printer/{name}/meshes", web.meshes_json),
        Route("/events", web.events),
        Mount("/static", app=StaticFiles(directory=STATIC), name="static"),
    ]
    return Starlette(routes=routes, exception_handlers={HTTPException: web.http_error, Exception: web.server_error})


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="tapcell web", description="Tap history in the browser (read-only): "
                                     "the fleet, each printer's taps and meshes, live while a monitor writes.")
    parser.add_argument("--db", metavar="URL", help="the store: a path, sqlite:///PATH or postgresql://... "
                        "(default: ~/.local/share/tapcell/taps.db)")
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (default: %(default)s; "
                        "0.0.0.0 to open it to the network)")
    parser.add_argument("--port", type=int, default=7130, help="port (default: %(default)s)")
    args = parser.parse_args(argv)
    if not 0 < args.port < 65536:
        parser.error(f"--port: {args.port} is not a port (1..65535)")
    missing = missing_assets()
    if missing:
        print(f"tapcell web: {', '.join(missing)} missing from {STATIC / 'vendor'}: run 'make web-assets' "
              "(uPlot from the npm registry)", file=sys.stderr)
        return 2
    try:
        store = Store(args.db, create=False)
    except StoreError as exc:
        print(f"tapcell web: {exc}", file=sys.stderr)
        return 2
    import uvicorn

    print(f"tapcell web: {store.shown} on http://{args.host}:{args.port}/", file=sys.stderr, flush=True)
    try:
        # Open pages keep an event stream: on Ctrl-C, close them after 2 s instead of waiting on them.
        uvicorn.run(create_app(store), host=args.host, port=args.port, log_level="warning",
                    timeout_graceful_shutdown=2)
    finally:
        store.close()
    return 0
