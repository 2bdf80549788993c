"""The HMI's web application (Starlette): settings, the wiring the routes share, the stack.

Pages and endpoints are in :mod:`~cell.hmi.pages` (status, trend, recipes, reports),
:mod:`~cell.hmi.line` (the line view, when the HMI has the plant historian's DSN) and
:mod:`~cell.hmi.auth` (login, logout, sessions, CSRF); the middleware in front of them in
:mod:`~cell.hmi.guard`.

Security: looking is open to loopback clients; any other client must log in to see
anything. Saving a recipe needs a logged-in user whose role may edit
(:data:`cell.hmi.users.EDIT_ROLES`). Sessions are signed cookies (a key made at start, so a
restart logs everyone out), HttpOnly, SameSite=Strict, 8 hours, and end at logout or when
the user's password is set again (:class:`~cell.hmi.users.Users`). Every POST carries the
session's CSRF token and, if the browser sends an ``Origin``, it must be this server's;
otherwise 403 before the body is read. Failed logins are slowed down per user and client
(:class:`~cell.hmi.throttle.LoginThrottle`). Requests must name an allowed host; bodies are
bounded; blocking work runs in bounded pools (:mod:`~cell.hmi.work`, 503 when full). Pages
carry a strict Content-Security-Policy, ``Cache-Control: no-store`` and a same-origin
referrer policy;
reports are served sandboxed.

Times on the pages are local, 24-hour, ``YYYY-MM-DD HH:MM:SS`` (:func:`cell.hmi.pages.local_time`;
the scripts format theirs the same way).
"""
from __future__ import annotations

import secrets
from dataclasses import dataclass
from pathlib import Path

from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.middleware.sessions import SessionMiddleware
from starlette.requests import Request
from starlette.responses import JSONResponse, PlainTextResponse, RedirectResponse, Response
from starlette.routing import Mount
from starlette.staticfiles import StaticFiles
from starlette.templating import Jinja2Templates

from cell.hmi import auth, line, pages
from cell.hmi.guard import BodyLimit, ResourceErrors, ResponseHeaders, TrustedHost
from cell.hmi.netguard import RateLimitedLog
from cell.hmi.recipes import RecipeDesk
from cell.hmi.status import TrendCache
from cell.hmi.throttle import LoginThrottle
from cell.hmi.users import EDIT_ROLES, Users
from cell.hmi.work import Busy, WorkPool

HERE = Path(__file__).resolve().parent
SESSION_S = 8 * 3600
MAX_BODY = 256 * 1024                 #: the largest request body any route takes (413 above)
PAGE_CSP = ("default-src 'self'; img-src 'self' data:; style-src 'self'; script-src 'self'; "
            "frame-ancestors 'none'; form-action 'self'; base-uri 'none'")


@dataclass(frozen=True)
class HmiSettings:
    """What the HMI serves: the recipe desk, the log, the users, the reports folder and,
    optionally, the PLC link to read status registers from (``plc``: (host, port)).

    ``listen_host`` and ``allowed_hosts``: the host names requests may name (besides
    localhost, 127.0.0.1 and [::1]); ``trusted_proxies``: addresses (or networks) whose
    ``X-Forwarded-Proto``/``-Host`` are honoured. ``check_slots``: recipe checks at once.
    """

    desk: RecipeDesk
    log_path: Path
    users: Users
    reports: Path
    plc: tuple[str, int] | None = None
    cell_name: str = "cell"
    throttle: LoginThrottle | None = None      #: default: LoginThrottle() on wall time
    listen_host: str = "127.0.0.1"
    allowed_hosts: tuple[str, ...] = ()
    trusted_proxies: tuple[str, ...] = ("127.0.0.1", "::1")
    check_slots: int = 2
    #: the plant historian's PostgreSQL (libpq string): the line view (:mod:`cell.hmi.line`); None: off
    line_dsn: str | None = None
    #: (cell id ``site/line/cell``, URL of that cell's HMI) pairs: the line view links there
    line_links: tuple[tuple[str, str], ...] = ()


class Hmi:
    """What the routes share: the settings, the templates, the work pools (``checks``:
    recipe checks and saves; ``reads``: the log, the PLC, the reports; ``logins``: password
    hashes), the login throttle, the trend cache, the rate-limited log."""

    def __init__(self, s: HmiSettings):
        import logging
        self.s = s
        self.templates = Jinja2Templates(directory=str(HERE / "templates"))
        self.templates.env.filters["when"] = pages.local_time
        self.throttle = s.throttle if s.throttle is not None else LoginThrottle()
        self.checks = WorkPool("recipe checks", s.check_slots)
        self.reads = WorkPool("log reads", 4)
        self.logins = WorkPool("password checks", 2)
        self.trend = TrendCache(s.log_path, s.desk.directory, self.reads, WorkPool("trend drawings", 1))
        self.log = RateLimitedLog(logging.getLogger("cell.hmi"))

    def may_view(self, request: Request) -> bool:
        return auth.loopback(request) or auth.session_user(self, request) is not None

    def view_refusal(self, request: Request) -> Response | None:
        """None if the client may look; else 401 (API) or a redirect to the login."""
        if self.may_view(request):
            return None
        if request.url.path.startswith("/api/"):
            return JSONResponse({"error": "log in first"}, status_code=401)
        return RedirectResponse("/login", status_code=303)

    def page(self, request: Request, name: str, status_code: int = 200, headers: dict | None = None,
             **context) -> Response:
        user = auth.session_user(self, request)
        context.update(user=user, csrf=auth.csrf_token(request), cell_name=self.s.cell_name,
                       can_edit=(user or {}).get("role") in EDIT_ROLES, line_view=bool(self.s.line_dsn))
        resp = self.templates.TemplateResponse(request, name, context, status_code=status_code, headers=headers)
        resp.headers["Content-Security-Policy"] = PAGE_CSP
        return resp


def _busy(request: Request, exc: Exception) -> Response:
    headers = {"Retry-After": "1"}
    if request.url.path.startswith("/api/"):
        return JSONResponse({"ok": False, "error": str(exc)}, status_code=503, headers=headers)
    return PlainTextResponse(str(exc), status_code=503, headers=headers)


def create_app(s: HmiSettings) -> Starlette:
    """The application for ``s``; ``app.state.hmi`` is its :class:`Hmi`."""
    hmi = Hmi(s)
    routes = [*pages.routes(hmi), *line.routes(hmi), *auth.routes(hmi),
              Mount("/static", StaticFiles(directory=str(HERE / "static")), name="static")]
    middleware = [
        Middleware(ResponseHeaders),
        Middleware(ResourceErrors, log=hmi.log),
        Middleware(TrustedHost, allowed=(s.listen_host, *s.allowed_hosts), trusted_proxies=s.trusted_proxies),
        Middleware(BodyLimit, max_bytes=MAX_BODY),
        Middleware(SessionMiddleware, secret_key=secrets.token_urlsafe(32), session_cookie="cell_hmi",
                   max_age=SESSION_S, same_site="strict", https_only=False),
    ]
    app = Starlette(routes=routes, middleware=middleware, exception_handlers={Busy: _busy})
    app.state.hmi = hmi
    return app
