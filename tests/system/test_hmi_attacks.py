"""The HMI under attack from loopback without a login, on the network level: a real uvicorn
server (the product's :func:`cell.hmi.server.serve`) on a free loopback port, as a process
of its own where the attack needs one (a descriptor limit, its own TMPDIR, signals) or in a
thread of the test. Each test is an attack that knocked the HMI over before; it asserts
what the HMI does, never how long it takes: waits are bounded polls of state (a socket
closed, a file made, a line logged), and a bound that passes is a failure of the HMI.
"""
from __future__ import annotations

import collections
import concurrent.futures
import dataclasses
import http.client
import json
import re
import select
import shutil
import signal
import socket
import threading
import time
from pathlib import Path

import pytest

from tests.system.hmi_cell import PASSWORD, USER, HmiProcess, hmi_server, poll

REPO_RECIPES = Path(__file__).resolve().parents[2] / "recipes"
WAIT_S = 60
pytestmark = pytest.mark.timeout(300)


@dataclasses.dataclass
class Files:
    recipes: Path
    db: Path
    users: Path


@pytest.fixture
def files(tmp_path) -> Files:
    from cell.hmi.users import set_user
    recipes = tmp_path / "recipes"
    shutil.copytree(REPO_RECIPES, recipes)
    set_user(tmp_path / "users.json", USER, "maintenance", PASSWORD)
    return Files(recipes, tmp_path / "cell.sqlite", tmp_path / "users.json")


def hmi(tmp_path: Path, files: Files, **kw) -> HmiProcess:
    return HmiProcess(tmp_path, files.recipes, files.db, files.users, **kw)


def request(port: int, method: str, path: str, body: bytes | None = None, headers: dict | None = None,
            timeout: float = WAIT_S) -> tuple[int, dict, bytes]:
    """One request on a connection of its own: (status, headers, body)."""
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
    try:
        c.request(method, path, body=body, headers=headers or {})
        r = c.getresponse()
        return r.status, {k.lower(): v for k, v in r.getheaders()}, r.read()
    finally:
        c.close()


def session(port: int) -> tuple[str, str]:
    """(Cookie header, CSRF token) of a fresh anonymous session (the login page's)."""
    status, headers, body = request(port, "GET", "/login")
    assert status == 200
    cookie = headers["set-cookie"].split(";")[0]
    return cookie, re.search(rb'name="csrf" value="([^"]+)"', body).group(1).decode()


def raw(port: int, head: str) -> socket.socket:
    """A connection that has sent ``head`` (request line and headers, CRLF-separated)."""
    s = socket.create_connection(("127.0.0.1", port), timeout=WAIT_S)
    s.sendall(head.replace("\n", "\r\n").encode())
    return s


def answer(s: socket.socket) -> bytes:
    """What the server sends until it closes the connection."""
    out = b""
    while True:
        try:
            data = s.recv(65536)
        except ConnectionResetError:
            return out
        if not data:
            return out
        out += data


# ---------------------------------------------------------------------------- 1: check floods
@pytest.mark.slow
def test_a_flood_of_recipe_checks_is_refused_busy_and_the_pages_stay_up(tmp_path, files):
    """40 checks at once that never end (the alias bomb before yamlio refused aliases): only
    as many run as there are slots; the others are answered 503 at once, and the status
    pages, which read the log in a pool of their own, still answer."""
    markers = tmp_path / "checks"
    markers.mkdir()
    text = (files.recipes / "bracket-a.yaml").read_text()
    with hmi(tmp_path, files, block_checks=markers) as h:
        cookie, token = session(h.port)
        answers: list[int] = []

        def check() -> None:
            try:
                answers.append(request(h.port, "POST", "/api/recipes/bracket-a/validate",
                                       json.dumps({"text": text}).encode(),
                                       {"Cookie": cookie, "X-CSRF-Token": token, "Content-Type": "application/json"},
                                       timeout=None)[0])
            except OSError:
                pass                              # the server stopped at the end of the test
        for _ in range(40):
            threading.Thread(target=check, daemon=True).start()
        poll(lambda: answers.count(503) == 38, WAIT_S, "38 of 40 checks refused busy")
        assert len(list(markers.iterdir())) == 2          # the two slots, blocked
        assert request(h.port, "GET", "/")[0] == 200
        assert request(h.port, "GET", "/api/status")[0] == 200
        assert request(h.port, "GET", "/reports")[0] == 200


def test_sigterm_stops_the_server_with_checks_in_flight(tmp_path, files):
    markers = tmp_path / "checks"
    markers.mkdir()
    text = (files.recipes / "bracket-a.yaml").read_text()
    with hmi(tmp_path, files, block_checks=markers, limits={"graceful_s": 1}) as h:
        cookie, token = session(h.port)

        def check() -> None:
            try:
                request(h.port, "POST", "/api/recipes/bracket-a/validate", json.dumps({"text": text}).encode(),
                        {"Cookie": cookie, "X-CSRF-Token": token, "Content-Type": "application/json"}, timeout=None)
            except OSError:
                pass
        for _ in range(2):
            threading.Thread(target=check, daemon=True).start()
        poll(lambda: len(list(markers.iterdir())) == 2, WAIT_S, "two checks running")
        h.proc.send_signal(signal.SIGTERM)
        try:
            code = h.proc.wait(timeout=WAIT_S)
        except Exception:
            pytest.fail(f"SIGTERM did not stop the HMI with checks in flight: {h.log()[-2000:]}")
        assert code in (0, -signal.SIGTERM)


# ---------------------------------------------------------------------------- 2: bodies
def test_a_chunked_multipart_login_is_refused_before_its_body_and_nothing_is_spooled(tmp_path, files):
    spool = tmp_path / "spool"
    spool.mkdir()
    with hmi(tmp_path, files, env={"TMPDIR": str(spool)}) as h:
        cookie, token = session(h.port)
        s = raw(h.port, f"POST /login HTTP/1.1\nHost: 127.0.0.1:{h.port}\nCookie: {cookie}\n"
                        "Content-Type: multipart/form-data; boundary=XyZ\nTransfer-Encoding: chunked\n\n")
        part = (f"--XyZ\r\nContent-Disposition: form-data; name=\"csrf\"\r\n\r\n{token}\r\n--XyZ\r\n"
                "Content-Disposition: form-data; name=\"f\"; filename=\"big.bin\"\r\n\r\n").encode() + b"x" * (3 << 20)
        try:
            for i in range(0, len(part), 65536):   # 3 MB, the body never ends (no last chunk)
                piece = part[i:i + 65536]
                s.sendall(b"%x\r\n" % len(piece) + piece + b"\r\n")
        except OSError:
            pass                                    # refused and closed while sending: as it should
        reply = answer(s)
        s.close()
        assert reply.startswith(b"HTTP/1.1 415") and b"connection: close" in reply.lower()
        assert list(spool.iterdir()) == []


def test_a_post_without_a_session_token_is_refused_before_its_body(tmp_path, files):
    with hmi(tmp_path, files) as h:
        s = raw(h.port, f"POST /login HTTP/1.1\nHost: 127.0.0.1:{h.port}\n"
                        "Content-Type: application/x-www-form-urlencoded\nContent-Length: 4000\n\n")
        reply = answer(s)                          # the body is never sent
        s.close()
        assert reply.startswith(b"HTTP/1.1 403")


def test_a_chunked_body_past_the_limit_is_refused_and_the_rest_never_read(tmp_path, files):
    with hmi(tmp_path, files) as h:
        cookie, token = session(h.port)
        s = raw(h.port, f"POST /api/recipes/bracket-a/validate HTTP/1.1\nHost: 127.0.0.1:{h.port}\n"
                        f"Cookie: {cookie}\nX-CSRF-Token: {token}\nContent-Type: application/json\n"
                        "Transfer-Encoding: chunked\n\n")
        chunk = b"10000\r\n" + b" " * 0x10000 + b"\r\n"
        sent, reply = 0, b""
        try:
            while sent < 100 << 20 and not reply:
                s.sendall(chunk)
                sent += 0x10000
                if select.select([s], [], [], 0)[0]:
                    reply = s.recv(65536)
        except OSError:
            pass
        if not reply:
            try:
                reply = answer(s)
            except OSError:
                reply = b""
        s.close()
        assert sent < 32 << 20, f"the server read {sent >> 20} MB of a body it refuses"
        assert reply == b"" or reply.startswith(b"HTTP/1.1 413")
        assert request(h.port, "GET", "/api/status")[0] == 200


# ---------------------------------------------------------------------------- 3: the trend
def test_concurrent_trend_requests_share_one_drawing_per_new_cycle(tmp_path, files):
    from cell.cyclelog import CycleLog, CycleRecord
    from cell.hmi.server import settings_from
    log = CycleLog(files.db)
    try:
        def add(i: int) -> None:
            log.add_cycle(CycleRecord(part_id=i, recipe="bracket-a", recipe_hash="0" * 64, status="done",
                                      started_at=f"2026-11-23T10:{i // 60:02d}:{i % 60:02d}+00:00",
                                      finished_at=f"2026-11-23T10:{i // 60:02d}:{i % 60:02d}+00:00",
                                      cycle_time_s=1.0, initial_error_mm=0.3, final_error_mm=0.02 + 0.0001 * i,
                                      verify_error_mm=0.021, moves=2))
        for i in range(200):
            add(i)
        settings = settings_from(None, str(files.users), str(tmp_path / "reports"), None, str(files.recipes),
                                 str(files.db))
        with hmi_server(settings) as (url, server):
            port = int(url.rsplit(":", 1)[1])
            trend = server.config.app.state.hmi.trend
            with concurrent.futures.ThreadPoolExecutor(100) as pool:
                got = list(pool.map(lambda _: request(port, "GET", "/trend.png"), range(100)))
            assert {g[0] for g in got} == {200} and len({g[2] for g in got}) == 1
            assert got[0][2].startswith(b"\x89PNG")
            assert trend.renders == 1
            assert request(port, "GET", "/trend.png")[2] == got[0][2] and trend.renders == 1
            add(200)                                              # a new cycle: one more drawing
            with concurrent.futures.ThreadPoolExecutor(20) as pool:
                again = list(pool.map(lambda _: request(port, "GET", "/trend.png"), range(20)))
            assert {g[0] for g in again} == {200} and trend.renders == 2
    finally:
        log.close()


# ---------------------------------------------------------------------------- 4: connections
def test_slow_connections_by_the_hundred_do_not_lock_a_client_out(tmp_path, files):
    """400 connections that never finish their headers, against a process allowed 256
    descriptors: the oldest of them are shed, and a new client is served."""
    with hmi(tmp_path, files, nofile=256) as h:
        held = [raw(h.port, f"GET / HTTP/1.1\nHost: 127.0.0.1\nX-Slow: ") for _ in range(400)]
        try:
            status, _, body = request(h.port, "GET", "/api/status")
            assert status == 200 and b"cycles_total" in body
        finally:
            for s in held:
                s.close()
        assert "Traceback" not in h.log()


def test_a_request_that_never_completes_is_closed(tmp_path, files):
    with hmi(tmp_path, files, limits={"request_timeout_s": 2}) as h:
        headers = raw(h.port, f"GET / HTTP/1.1\nHost: 127.0.0.1:{h.port}\n")
        assert _closed_while_dribbling(headers, b"X-Slow: a\r\n" * 400), "headers sent slowly kept open"
        body = raw(h.port, f"POST /login HTTP/1.1\nHost: 127.0.0.1:{h.port}\n"
                           "Content-Type: application/x-www-form-urlencoded\nContent-Length: 2000\n\n")
        assert _closed_while_dribbling(body, b"a" * 1000), "a body sent slowly kept open"
        assert request(h.port, "GET", "/")[0] == 200


def _closed_while_dribbling(s: socket.socket, feed: bytes) -> bool:
    """Send ``feed`` a byte every 0.2 s (the attacker's pace) until the server closes the
    connection (True) or ``WAIT_S`` passes (False)."""
    deadline = time.monotonic() + WAIT_S
    for i in range(len(feed)):
        if time.monotonic() > deadline:
            break
        ready = select.select([s], [], [], 0.2)[0]
        if ready:
            try:
                if not s.recv(65536):
                    return True
            except OSError:
                return True
            continue
        try:
            s.send(feed[i:i + 1])
        except OSError:
            return True
    return False


@pytest.mark.slow
def test_running_out_of_descriptors_logs_a_line_not_a_traceback_per_attempt(tmp_path, files):
    """The cap above what 128 descriptors allow, so accepting fails (EMFILE) while 300
    connections are held: one line for it, no traceback; once the held requests time out
    the server accepts again and serves."""
    with hmi(tmp_path, files, nofile=128, limits={"max_connections": 1000, "request_timeout_s": 3}) as h:
        held = [raw(h.port, f"GET / HTTP/1.1\nHost: 127.0.0.1\nX-Slow: ") for _ in range(300)]
        try:
            poll(lambda: "accept" in h.log(), WAIT_S, "the accept failure logged")
            assert request(h.port, "GET", "/api/status", timeout=120)[0] == 200
        finally:
            for s in held:
                s.close()
        log = h.log()
        assert "Traceback" not in log, log[-3000:]
        assert sum("accept" in line for line in log.splitlines()) <= 2, log[-3000:]


# ---------------------------------------------------------------------------- 5: logins
def test_concurrent_login_guesses_get_no_more_password_checks_than_the_throttle_allows(tmp_path, files):
    """300 wrong passwords at once from one client: each is reserved with the throttle
    before its hash is checked, so only the free tries are checked (401); the others are
    refused unchecked (429), or busy (503)."""
    from cell.clock import ManualClock
    from cell.hmi.server import settings_from
    from cell.hmi.throttle import LoginThrottle
    settings = settings_from(None, str(files.users), str(tmp_path / "reports"), None, str(files.recipes),
                             str(files.db))
    settings = dataclasses.replace(settings, throttle=LoginThrottle(ManualClock(0.0)))
    with hmi_server(settings) as (url, _):
        port = int(url.rsplit(":", 1)[1])
        cookie, token = session(port)
        form = f"csrf={token}&user={USER}&password=wrong-guess".encode()

        def guess(_: int) -> int:
            return request(port, "POST", "/login", form, {"Cookie": cookie,
                                                           "Content-Type": "application/x-www-form-urlencoded"})[0]
        with concurrent.futures.ThreadPoolExecutor(64) as pool:
            codes = collections.Counter(pool.map(guess, range(300)))
    assert codes[401] <= 3 and codes[429] > 0 and set(codes) <= {401, 429, 503}, codes
