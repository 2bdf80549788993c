"""The HMI's pages and JSON endpoints (login and logout are in :mod:`cell.hmi.auth`).

``/`` status and the last cycles (the page polls ``/api/status`` every second),
``/trend.png`` the accuracy trend (:class:`~cell.hmi.status.TrendCache`), ``/recipes`` and
``/recipes/{name}`` (view, what the controller made of the file, diff against the active
version, edit with validation as you type: ``POST /api/recipes/{name}/validate`` and
``/save``, then ``GET /api/recipes/{name}/decision?sha256=`` until the controller decides),
``/reports`` (the HTML reports under the reports folder, served sandboxed).

Times are shown by :func:`local_time`. Every blocking call runs in one of the
:class:`~cell.hmi.app.Hmi` pools; a full pool raises :class:`~cell.hmi.work.Busy`, which
the application answers 503.
"""
from __future__ import annotations

from datetime import datetime, timezone
from typing import TYPE_CHECKING

from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, PlainTextResponse, Response
from starlette.routing import Route

from cell.errors import ConfigError
from cell.hmi import status as st
from cell.hmi.auth import Refused, post_refusal, read_json, session_user
from cell.hmi.recipes import SaveRefused
from cell.hmi.users import EDIT_ROLES

if TYPE_CHECKING:
    from cell.hmi.app import Hmi

REPORT_TYPES = {".html": "text/html", ".png": "image/png", ".svg": "image/svg+xml", ".css": "text/css",
                ".json": "application/json", ".txt": "text/plain"}


def local_time(iso: str | None) -> str:
    """An ISO 8601 time as this machine's local time, ``YYYY-MM-DD HH:MM:SS`` (24-hour),
    the one format of every time on the pages (the scripts write theirs the same way); the
    text itself if it is not a time, '' for None."""
    if not iso:
        return ""
    try:
        t = datetime.fromisoformat(str(iso).replace("Z", "+00:00"))
    except ValueError:
        return str(iso)
    return (t.astimezone() if t.tzinfo else t).strftime("%Y-%m-%d %H:%M:%S")


def _errors(message: str) -> list[dict]:
    return [{"line": None, "field": "(file)", "message": message}]


def routes(hmi: Hmi) -> list[Route]:
    s = hmi.s
    desk = s.desk

    # ------------------------------------------------------------------ status
    async def index(request: Request) -> Response:
        if (r := hmi.view_refusal(request)) is not None:
            return r
        has_cycles = await hmi.reads.run(st.trend_key, s.log_path, None) is not None
        return hmi.page(request, "index.html", plc=s.plc, has_cycles=has_cycles)

    def read_status() -> dict:
        out = st.log_status(s.log_path)
        out["plc"] = st.plc_status(*s.plc) if s.plc else None
        return out

    async def api_status(request: Request) -> Response:
        if (r := hmi.view_refusal(request)) is not None:
            return r
        return JSONResponse(await hmi.reads.run(read_status))

    async def trend(request: Request) -> Response:
        if (r := hmi.view_refusal(request)) is not None:
            return r
        png = await hmi.trend.png()
        if png is None:
            return PlainTextResponse("no cycles logged yet", status_code=404)
        return Response(png, media_type="image/png")

    # ------------------------------------------------------------------ recipes
    async def recipes(request: Request) -> Response:
        if (r := hmi.view_refusal(request)) is not None:
            return r
        return hmi.page(request, "recipes.html", recipes=await hmi.checks.run(desk.list))

    async def recipe(request: Request) -> Response:
        if (r := hmi.view_refusal(request)) is not None:
            return r
        name = request.path_params["name"]
        try:
            view, diff = await hmi.checks.run(lambda: (desk.view(name), desk.diff(name)))
        except ConfigError as exc:
            return hmi.page(request, "error.html", status_code=404, message=str(exc))
        return hmi.page(request, "recipe.html", r=view, diff=diff)

    def validate(name: str, text: str) -> dict:
        out = desk.validate(name, text)
        out["diff"] = desk.diff(name, text)
        return out

    async def api_validate(request: Request) -> Response:
        if (r := hmi.view_refusal(request)) is not None:
            return r
        name = request.path_params["name"]
        try:
            if (refused := post_refusal(request, header_token=True)) is not None:
                raise refused
            doc = await read_json(request)
            out = await hmi.checks.run(validate, name, doc.get("text", ""))
        except Refused as exc:
            return JSONResponse({"ok": False, "error": str(exc), "errors": _errors(str(exc))}, status_code=exc.status)
        except ConfigError as exc:
            return JSONResponse({"ok": False, "errors": _errors(str(exc))}, status_code=404)
        return JSONResponse(out)

    async def api_save(request: Request) -> Response:
        name = request.path_params["name"]
        try:
            if (refused := post_refusal(request, header_token=True)) is not None:
                raise refused
            user = session_user(hmi, request)
            if user is None:
                raise Refused(401, "log in to edit recipes")
            if user["role"] not in EDIT_ROLES:
                raise Refused(403, f"role {user['role']} may not edit recipes")
            doc = await read_json(request)
            saved = await hmi.checks.run(desk.save, name, doc.get("text", ""), str(doc.get("base_sha256", "")),
                                         user["name"], user["role"])
        except Refused as exc:
            return JSONResponse({"ok": False, "error": str(exc)}, status_code=exc.status)
        except SaveRefused as exc:
            return JSONResponse({"ok": False, "error": str(exc), "errors": exc.errors}, status_code=exc.status)
        except ConfigError as exc:
            return JSONResponse({"ok": False, "error": str(exc)}, status_code=404)
        return JSONResponse({"ok": True, "sha256": saved.sha256, "path": saved.path})

    async def api_decision(request: Request) -> Response:
        if (r := hmi.view_refusal(request)) is not None:
            return r
        sha = request.query_params.get("sha256", "")
        out = await hmi.reads.run(desk.decision, request.path_params["name"], sha)
        if out.get("audit"):
            out["audit"] = {**out["audit"], "at_local": local_time(out["audit"].get("at"))}
        return JSONResponse(out)

    # ------------------------------------------------------------------ reports
    def report_files() -> list[dict]:
        root = s.reports.resolve()
        if not root.is_dir():
            return []
        out = []
        for p in sorted(root.rglob("*.html")):
            rel = p.relative_to(root)
            if p.is_file() and root in p.resolve().parents and not any(x.startswith(".") for x in rel.parts):
                mtime = datetime.fromtimestamp(p.stat().st_mtime, timezone.utc).isoformat()
                out.append({"path": str(rel), "at": mtime})
        return out

    async def reports(request: Request) -> Response:
        if (r := hmi.view_refusal(request)) is not None:
            return r
        return hmi.page(request, "reports.html", files=await hmi.reads.run(report_files), folder=str(s.reports))

    async def report_file(request: Request) -> Response:
        if (r := hmi.view_refusal(request)) is not None:
            return r
        root = s.reports.resolve()
        path = (root / request.path_params["path"]).resolve()
        if root not in path.parents or not path.is_file() or path.suffix.lower() not in REPORT_TYPES:
            return PlainTextResponse("no such report file", status_code=404)
        return FileResponse(path, media_type=REPORT_TYPES[path.suffix.lower()],
                            headers={"Content-Security-Policy": "sandbox allow-scripts"})

    return [
        Route("/", index), Route("/api/status", api_status), Route("/trend.png", trend),
        Route("/recipes", recipes), Route("/recipes/{name}", recipe),
        Route("/api/recipes/{name}/validate", api_validate, methods=["POST"]),
        Route("/api/recipes/{name}/save", api_save, methods=["POST"]),
        Route("/api/recipes/{name}/decision", api_decision),
        Route("/reports", reports), Route("/reports/{path:path}", report_file),
    ]
