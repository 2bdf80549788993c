"""The HMI's web application (Starlette): pages, JSON endpoints, login and CSRF.

Pages: ``/`` status and the last cycles (the page polls ``/api/status`` every second),
``/trend.png`` the accuracy trend, ``/recipes`` and ``/recipes/{name}`` (view, diff against
the active version, edit with validation as you type), ``/reports`` (the HTML reports under
the reports folder), ``/login``.

Security: looking is open to loopback clients; any other client must log in to see
anything. Saving a recipe needs a logged-in user whose role may edit
(:data:`cell.hmi.users.EDIT_ROLES`). Sessions are signed cookies (itsdangerous, a key made
at start, so a restart logs everyone out), HttpOnly, SameSite=Strict, 8 hours. Every POST
carries the session's CSRF token (form field ``csrf`` or header ``X-CSRF-Token``) and, if
the browser sends an ``Origin``, it must be this server's; otherwise 403 and nothing
happens. Login replaces the session (no fixation); failed logins are throttled
(:class:`~cell.hmi.users.LoginThrottle`). Our pages carry a strict Content-Security-Policy;
reports are served sandboxed.
"""
from __future__ import annotations

import hmac
import ipaddress
import json
import secrets
from dataclasses import dataclass
from pathlib import Path

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.middleware import Middleware
from starlette.middleware.sessions import SessionMiddleware
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, PlainTextResponse, RedirectResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles
from starlette.templating import Jinja2Templates

from cell.errors import ConfigError
from cell.hmi import status as st
from cell.hmi.recipes import RecipeDesk, SaveRefused
from cell.hmi.users import EDIT_ROLES, LoginThrottle, Users

HERE = Path(__file__).resolve().parent
SESSION_S = 8 * 3600
MAX_BODY = 256 * 1024                 #: a request body larger than this is refused (413)
REPORT_TYPES = {".html": "text/html", ".png": "image/png", ".svg": "image/svg+xml", ".css": "text/css",
                ".json": "application/json", ".txt": "text/plain"}
PAGE_CSP = ("default-src 'self'; img-src 'self' data:; style-src 'self'; script-src 'self'; "
            "frame-ancestors 'none'; form-action 'self'; base-uri 'none'")


@dataclass(frozen=True)
class HmiSettings:
    """What the HMI serves: the recipe desk, the log, the users, the reports folder and,
    optionally, the PLC link to read status registers from (``plc``: (host, port))."""

    desk: RecipeDesk
    log_path: Path
    users: Users
    reports: Path
    plc: tuple[str, int] | None = None
    cell_name: str = "cell"
    throttle: LoginThrottle | None = None      #: default: 5 failures per user or client in 5 min


def create_app(s: HmiSettings) -> Starlette:
    templates = Jinja2Templates(directory=str(HERE / "templates"))
    throttle = s.throttle or LoginThrottle()

    def session_user(request: Request) -> dict | None:
        u = request.session.get("user")
        return u if isinstance(u, dict) and "name" in u and "role" in u else None

    def csrf_token(request: Request) -> str:
        if "csrf" not in request.session:
            request.session["csrf"] = secrets.token_urlsafe(32)
        return request.session["csrf"]

    def loopback(request: Request) -> bool:
        try:
            return request.client is not None and ipaddress.ip_address(request.client.host).is_loopback
        except ValueError:
            return False

    def may_view(request: Request) -> bool:
        return loopback(request) or session_user(request) is not None

    def page(request: Request, name: str, status_code: int = 200, **context) -> Response:
        context.update(user=session_user(request), csrf=csrf_token(request), cell_name=s.cell_name,
                       can_edit=(session_user(request) or {}).get("role") in EDIT_ROLES)
        resp = templates.TemplateResponse(request, name, context, status_code=status_code)
        resp.headers["Content-Security-Policy"] = PAGE_CSP
        return resp

    def guard_view(request: Request) -> Response | None:
        if may_view(request):
            return None
        if request.url.path.startswith("/api/"):
            return JSONResponse({"error": "log in first"}, status_code=401)
        return RedirectResponse("/login", status_code=303)

    async def guard_post(request: Request, form: dict | None = None) -> Response | None:
        """403 unless the CSRF token matches and the Origin (if sent) is this server."""
        origin = request.headers.get("origin")
        if origin and origin.rstrip("/") != f"{request.url.scheme}://{request.headers.get('host', '')}":
            return JSONResponse({"error": "cross-site request refused"}, status_code=403)
        sent = (form or {}).get("csrf") or request.headers.get("x-csrf-token") or ""
        want = request.session.get("csrf", "")
        if not want or not hmac.compare_digest(str(sent), str(want)):
            return JSONResponse({"error": "missing or wrong CSRF token: reload the page"}, status_code=403)
        if int(request.headers.get("content-length") or 0) > MAX_BODY:
            return JSONResponse({"error": "request too large"}, status_code=413)
        return None

    async def json_body(request: Request) -> dict:
        body = await request.body()
        if len(body) > MAX_BODY:
            raise SaveRefused(413, "request too large")
        try:
            doc = json.loads(body)
        except ValueError:
            raise SaveRefused(400, "the body must be JSON") from None
        if not isinstance(doc, dict) or not isinstance(doc.get("text", ""), str):
            raise SaveRefused(400, "the body must be a JSON object with a string 'text'")
        return doc

    # ------------------------------------------------------------------ status
    async def index(request: Request) -> Response:
        return guard_view(request) or page(request, "index.html", plc=s.plc)

    async def api_status(request: Request) -> Response:
        if (r := guard_view(request)) is not None:
            return r
        out = await run_in_threadpool(st.log_status, s.log_path)
        out["plc"] = await run_in_threadpool(st.plc_status, *s.plc) if s.plc else None
        return JSONResponse(out, headers={"Cache-Control": "no-store"})

    async def trend(request: Request) -> Response:
        if (r := guard_view(request)) is not None:
            return r
        png = await run_in_threadpool(st.trend_png, s.log_path, s.desk.directory)
        if png is None:
            return PlainTextResponse("no cycles logged yet", status_code=404)
        return Response(png, media_type="image/png", headers={"Cache-Control": "no-store"})

    # ------------------------------------------------------------------ recipes
    async def recipes(request: Request) -> Response:
        if (r := guard_view(request)) is not None:
            return r
        return page(request, "recipes.html", recipes=await run_in_threadpool(s.desk.list))

    async def recipe(request: Request) -> Response:
        if (r := guard_view(request)) is not None:
            return r
        name = request.path_params["name"]
        try:
            view = await run_in_threadpool(s.desk.view, name)
            diff = await run_in_threadpool(s.desk.diff, name)
        except ConfigError as exc:
            return page(request, "error.html", status_code=404, message=str(exc))
        return page(request, "recipe.html", r=view, diff=diff)

    async def api_validate(request: Request) -> Response:
        if (r := guard_view(request) or await guard_post(request)) is not None:
            return r
        name = request.path_params["name"]
        try:
            doc = await json_body(request)
            out = await run_in_threadpool(s.desk.validate, name, doc.get("text", ""))
            out["diff"] = await run_in_threadpool(s.desk.diff, name, doc.get("text", ""))
        except SaveRefused as exc:
            return JSONResponse({"ok": False, "errors": exc.errors}, status_code=exc.status)
        except ConfigError as exc:
            return JSONResponse({"ok": False, "errors": [{"line": None, "field": "(file)", "message": str(exc)}]},
                                status_code=404)
        return JSONResponse(out)

    async def api_save(request: Request) -> Response:
        if (r := await guard_post(request)) is not None:
            return r
        user = session_user(request)
        if user is None:
            return JSONResponse({"ok": False, "error": "log in to edit recipes"}, status_code=401)
        if user["role"] not in EDIT_ROLES:
            return JSONResponse({"ok": False, "error": f"role {user['role']} may not edit recipes"},
                                status_code=403)
        name = request.path_params["name"]
        try:
            doc = await json_body(request)
            saved = await run_in_threadpool(s.desk.save, name, doc.get("text", ""),
                                            str(doc.get("base_sha256", "")), user["name"], user["role"])
        except SaveRefused as exc:
            return JSONResponse({"ok": False, "error": str(exc), "errors": exc.errors}, status_code=exc.status)
        except ConfigError as exc:
            return JSONResponse({"ok": False, "error": str(exc)}, status_code=404)
        return JSONResponse({"ok": True, "sha256": saved.sha256, "path": saved.path})

    async def api_decision(request: Request) -> Response:
        if (r := guard_view(request)) is not None:
            return r
        sha = request.query_params.get("sha256", "")
        out = await run_in_threadpool(s.desk.decision, request.path_params["name"], sha)
        return JSONResponse(out, headers={"Cache-Control": "no-store"})

    # ------------------------------------------------------------------ reports
    def report_files() -> list[str]:
        root = s.reports.resolve()
        if not root.is_dir():
            return []
        return sorted(str(p.relative_to(root)) for p in root.rglob("*.html")
                      if p.is_file() and root in p.resolve().parents
                      and not any(part.startswith(".") for part in p.relative_to(root).parts))

    async def reports(request: Request) -> Response:
        if (r := guard_view(request)) is not None:
            return r
        return page(request, "reports.html", files=await run_in_threadpool(report_files), folder=str(s.reports))

    async def report_file(request: Request) -> Response:
        if (r := guard_view(request)) is not None:
            return r
        root = s.reports.resolve()
        path = (root / request.path_params["path"]).resolve()
        if root not in path.parents or not path.is_file() or path.suffix.lower() not in REPORT_TYPES:
            return PlainTextResponse("no such report file", status_code=404)
        return FileResponse(path, media_type=REPORT_TYPES[path.suffix.lower()],
                            headers={"Content-Security-Policy": "sandbox allow-scripts",
                                     "X-Content-Type-Options": "nosniff"})

    # ------------------------------------------------------------------ login
    async def login(request: Request) -> Response:
        if request.method == "GET":
            return page(request, "login.html", error=None, users=len(s.users),
                        next=request.query_params.get("next", "/"))
        form = dict(await request.form())
        if (r := await guard_post(request, form)) is not None:
            return r
        name, client = str(form.get("user", "")), request.client.host if request.client else "?"
        wait = throttle.blocked(name, client)
        if wait > 0:
            return page(request, "login.html", status_code=429, users=len(s.users), next=str(form.get("next", "/")),
                        error=f"too many failed logins: try again in {wait:.0f} s")
        who = await run_in_threadpool(s.users.authenticate, name, str(form.get("password", "")))
        if who is None:
            throttle.failed(name, client)
            return page(request, "login.html", status_code=401, error="unknown user or wrong password",
                        users=len(s.users), next=str(form.get("next", "/")))
        throttle.succeeded(name)
        request.session.clear()                       # a fresh session: no fixation
        request.session.update(user={"name": who[0], "role": who[1]}, csrf=secrets.token_urlsafe(32))
        nxt = str(form.get("next", "/"))
        return RedirectResponse(nxt if nxt.startswith("/") and not nxt.startswith("//") else "/", status_code=303)

    async def logout(request: Request) -> Response:
        form = dict(await request.form())
        if (r := await guard_post(request, form)) is not None:
            return r
        request.session.clear()
        return RedirectResponse("/", status_code=303)

    routes = [
        Route("/", index), Route("/api/status", api_status), Route("/trend.png", trend),
        Route("/recipes", recipes), Route("/recipes/{name}", recipe),
        Route("/api/recipes/{name}/validate", api_validate, methods=["POST"]),
        Route("/api/recipes/{name}/save", api_save, methods=["POST"]),
        Route("/api/recipes/{name}/decision", api_decision),
        Route("/reports", reports), Route("/reports/{path:path}", report_file),
        Route("/login", login, methods=["GET", "POST"]), Route("/logout", logout, methods=["POST"]),
        Mount("/static", StaticFiles(directory=str(HERE / "static")), name="static"),
    ]
    middleware = [Middleware(SessionMiddleware, secret_key=secrets.token_urlsafe(32), session_cookie="cell_hmi",
                             max_age=SESSION_S, same_site="strict", https_only=False)]
    return Starlette(routes=routes, middleware=middleware)
