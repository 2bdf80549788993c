"""Login, logout, sessions and the checks every POST passes before its body is read.

Session (a signed cookie, :class:`starlette.middleware.sessions.SessionMiddleware`):
``csrf`` (a random token, made with the first page) and, once logged in, ``user``: the
name and the stamp :meth:`cell.hmi.users.Users.authenticate` gave. :func:`session_user`
takes the role from the users file as it is now, and only while the stamp still holds, so
logout and ``cellctl hmi passwd`` end sessions at once.

A POST is refused (403) before anything of its body is read when its ``Origin`` is not
this server (the scheme and host a trusted proxy forwarded, :class:`cell.hmi.guard.TrustedHost`),
when the session has no CSRF token, or when an ``X-CSRF-Token`` header is sent and wrong;
JSON endpoints need that header. A form's token is checked after its body is read, bounded
to :data:`FORM_MAX` bytes, and parsed here (``application/x-www-form-urlencoded`` only).

Login: the attempt is reserved with the throttle before the password is checked (no
``await`` between the look and the count), and the check runs in the ``logins`` pool; a
full pool answers 503 before anything is reserved.
"""
from __future__ import annotations

import hmac
import ipaddress
import json
import secrets
from typing import TYPE_CHECKING
from urllib.parse import parse_qs, urlsplit

from starlette.requests import Request
from starlette.responses import JSONResponse, RedirectResponse, Response
from starlette.routing import Route

from cell.hmi.work import Busy

if TYPE_CHECKING:
    from cell.hmi.app import Hmi

FORM_MAX = 8 * 1024                  #: the largest form body (login, logout), bytes
_DEFAULT_PORTS = {"http": 80, "https": 443}


class Refused(Exception):
    """A request refused before or while its body was read: ``status`` and ``message``."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


def loopback(request: Request) -> bool:
    try:
        return request.client is not None and ipaddress.ip_address(request.client.host).is_loopback
    except ValueError:
        return False


def client_address(request: Request) -> str:
    """The peer's address (never a header's)."""
    return request.client.host if request.client else "?"


def csrf_token(request: Request) -> str:
    if "csrf" not in request.session:
        request.session["csrf"] = secrets.token_urlsafe(32)
    return request.session["csrf"]


def session_user(hmi: Hmi, request: Request) -> dict | None:
    """``{"name", "role"}`` of the session's user while its session holds, else None."""
    u = request.session.get("user")
    if not (isinstance(u, dict) and isinstance(u.get("name"), str) and isinstance(u.get("stamp"), str)):
        return None
    role = hmi.s.users.role(u["name"], u["stamp"])
    return {"name": u["name"], "role": role} if role else None


def _same_origin(origin: str, request: Request) -> bool:
    try:
        o = urlsplit(origin)
        want = urlsplit(f"{request.url.scheme}://{request.headers.get('host', '')}")
        return (o.scheme, o.hostname, o.port or _DEFAULT_PORTS.get(o.scheme)) == \
               (want.scheme, want.hostname, want.port or _DEFAULT_PORTS.get(want.scheme))
    except ValueError:
        return False


def _same_token(sent: str, want) -> bool:
    return bool(want) and hmac.compare_digest(str(sent).encode("utf-8", "replace"), str(want).encode("utf-8"))


def post_refusal(request: Request, header_token: bool) -> Refused | None:
    """Why a POST is refused before its body is read (None: read on). ``header_token``:
    the CSRF token must come in ``X-CSRF-Token`` (JSON endpoints), not in a form."""
    origin = request.headers.get("origin")
    if origin and not _same_origin(origin, request):
        return Refused(403, "cross-site request refused")
    want = request.session.get("csrf")
    sent = request.headers.get("x-csrf-token")
    if not want or (sent is None and header_token) or (sent is not None and not _same_token(sent, want)):
        return Refused(403, "missing or wrong CSRF token: reload the page")
    return None


async def read_form(request: Request) -> dict[str, str]:
    """The urlencoded form of ``request`` (first value of each field), its CSRF token
    checked. :raises Refused: not a form (415), too big (413), bad token (403)."""
    if request.headers.get("content-type", "").split(";")[0].strip().lower() != "application/x-www-form-urlencoded":
        raise Refused(415, "a form must be application/x-www-form-urlencoded")
    body = b""
    async for chunk in request.stream():
        body += chunk
        if len(body) > FORM_MAX:
            raise Refused(413, f"form too large (at most {FORM_MAX} bytes)")
    try:
        fields = parse_qs(body.decode("utf-8"), keep_blank_values=True, max_num_fields=16)
    except (UnicodeDecodeError, ValueError):
        raise Refused(400, "not a form") from None
    form = {k: v[0] for k, v in fields.items()}
    sent = request.headers.get("x-csrf-token") or form.get("csrf", "")
    if not _same_token(sent, request.session.get("csrf")):
        raise Refused(403, "missing or wrong CSRF token: reload the page")
    return form


async def read_json(request: Request) -> dict:
    """The JSON object of ``request`` with a string ``text`` (bounded by the body limit).
    :raises Refused: not JSON (415/400)."""
    if request.headers.get("content-type", "").split(";")[0].strip().lower() != "application/json":
        raise Refused(415, "the body must be application/json")
    try:
        doc = json.loads(await request.body())
    except ValueError:
        raise Refused(400, "the body must be JSON") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("text", ""), str):
        raise Refused(400, "the body must be a JSON object with a string 'text'")
    return doc


def _next(value: str) -> str:
    return value if value.startswith("/") and not value.startswith("//") and "\\" not in value else "/"


def routes(hmi: Hmi) -> list[Route]:
    s = hmi.s

    def login_page(request: Request, status: int, error: str | None, nxt: str, headers=None) -> Response:
        return hmi.page(request, "login.html", status_code=status, error=error or s.users.error,
                        users=len(s.users), next=_next(nxt), headers=headers)

    async def login(request: Request) -> Response:
        if request.method == "GET":
            return login_page(request, 200, None, request.query_params.get("next", "/"))
        try:
            if (r := post_refusal(request, header_token=False)) is not None:
                raise r
            form = await read_form(request)
        except Refused as exc:
            return JSONResponse({"error": str(exc)}, status_code=exc.status)
        name, password, nxt = form.get("user", ""), form.get("password", ""), form.get("next", "/")
        client = client_address(request)
        if hmi.logins.full():                         # before the reservation: nothing to take back
            raise Busy(f"the HMI is busy ({hmi.logins.slots} password checks running): try again in a moment")
        wait = hmi.throttle.attempt(name, client)
        if wait > 0:
            return login_page(request, 429, f"too many failed logins: try again in {max(1, round(wait))} s", nxt,
                              headers={"Retry-After": str(max(1, round(wait)))})
        who = await hmi.logins.run(s.users.authenticate, name, password)   # a slot is free: no Busy
        if who is None:
            return login_page(request, 401, "unknown user or wrong password", nxt)
        hmi.throttle.succeeded(name, client)
        request.session.clear()                       # a fresh session: no fixation
        request.session.update(user={"name": who[0], "stamp": who[2]}, csrf=secrets.token_urlsafe(32))
        return RedirectResponse(_next(nxt), status_code=303)

    async def logout(request: Request) -> Response:
        try:
            if (r := post_refusal(request, header_token=False)) is not None:
                raise r
            await read_form(request)
        except Refused as exc:
            return JSONResponse({"error": str(exc)}, status_code=exc.status)
        user = session_user(hmi, request)
        if user is not None:
            s.users.end_sessions(user["name"])        # every session of the user ends
        request.session.clear()
        return RedirectResponse("/", status_code=303)

    return [Route("/login", login, methods=["GET", "POST"]), Route("/logout", logout, methods=["POST"])]
