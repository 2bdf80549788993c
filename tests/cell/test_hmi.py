"""The maintenance HMI over HTTP (Starlette's in-process client against the real app, the
real recipe desk, and our real recipe store and cycle log standing in as the controller's
side): who may look and who may edit, what a save writes, and what the controller makes of it."""
from __future__ import annotations

import json
import os
import re
import stat

import pytest
from starlette.testclient import TestClient

from cell.cli import main
from cell.cyclelog import CycleLog
from cell.hmi.app import create_app
from cell.hmi.server import settings_from
from cell.hmi.users import Users, set_user
from cell.recipes.notes import note_path
from cell.recipes.store import RecipeStore

PASSWORD = "correct horse battery"


@pytest.fixture
def cell(rdir, tmp_path):
    """The controller's side: a recipe store on the folder, auditing into a real log."""
    log = CycleLog(tmp_path / "cell.sqlite")
    store = RecipeStore(rdir, commit=log.record_recipe_changes)
    store.refresh()
    yield store, log
    log.close()


@pytest.fixture
def hmi(rdir, tmp_path, cell):
    users = tmp_path / "users.json"
    set_user(users, "alice", "maintenance", PASSWORD)
    set_user(users, "victor", "viewer", PASSWORD)
    s = settings_from(None, str(users), str(tmp_path / "reports"), None, str(rdir), str(tmp_path / "cell.sqlite"))
    return create_app(s)


def client(app, host="127.0.0.1") -> TestClient:
    return TestClient(app, base_url="http://127.0.0.1:8080", client=(host, 50000))


def csrf(c: TestClient, page: str = "/login") -> str:
    return re.search(r'(?:name="csrf" value|data-csrf)="([^"]+)"', c.get(page).text).group(1)


def login(c: TestClient, user="alice", password=PASSWORD):
    return c.post("/login", data={"csrf": csrf(c), "user": user, "password": password}, follow_redirects=False)


def editor(c: TestClient, name: str) -> tuple[str, str]:
    """(csrf token, sha256 the editor loaded) of recipe ``name``'s page."""
    page = c.get(f"/recipes/{name}").text
    return re.search(r'data-csrf="([^"]+)"', page).group(1), re.search(r'data-sha="([^"]+)"', page).group(1)


def test_looking_is_open_on_loopback_and_needs_a_login_from_elsewhere(hmi):
    local = client(hmi)
    for path in ("/", "/recipes", "/recipes/pin-b", "/reports", "/api/status"):
        assert local.get(path).status_code == 200, path
    remote = client(hmi, host="192.168.10.77")
    assert remote.get("/recipes", follow_redirects=False).status_code == 303
    assert remote.get("/api/status").status_code == 401
    assert login(remote).status_code == 303
    assert remote.get("/recipes").status_code == 200


def test_a_bad_login_is_refused_and_the_session_cookie_is_strict(hmi):
    c = client(hmi)
    r = login(c, password="wrong password")
    assert r.status_code == 401 and "wrong password" in r.text
    assert login(c, user="mallory").status_code == 401
    assert 'id="who"' not in c.get("/").text
    r = login(c)
    cookie = r.headers["set-cookie"].lower()
    assert r.status_code == 303 and "httponly" in cookie and "samesite=strict" in cookie
    assert "alice (maintenance)" in c.get("/").text


def test_a_post_without_login_csrf_or_editing_role_is_refused_and_writes_nothing(hmi, rdir):
    path = rdir / "bracket-a.yaml"
    before = path.read_bytes()
    text = before.decode().replace("tolerance_mm: 0.08", "tolerance_mm: 0.09")
    anon = client(hmi)
    token, sha = editor(anon, "bracket-a")
    doc = {"text": text, "base_sha256": sha}
    assert anon.post("/api/recipes/bracket-a/save", json=doc, headers={"X-CSRF-Token": token}).status_code == 401
    alice = client(hmi)
    login(alice)
    token, sha = editor(alice, "bracket-a")
    assert alice.post("/api/recipes/bracket-a/save", json=doc).status_code == 403                  # no token
    assert alice.post("/api/recipes/bracket-a/save", json=doc, headers={"X-CSRF-Token": "forged"}).status_code == 403
    assert alice.post("/api/recipes/bracket-a/save", json=doc, headers={
        "X-CSRF-Token": token, "Origin": "http://evil.example"}).status_code == 403
    assert alice.post("/logout", data={"csrf": "forged"}).status_code == 403
    victor = client(hmi)
    login(victor, user="victor")
    token, _ = editor(victor, "bracket-a")
    assert victor.post("/api/recipes/bracket-a/save", json=doc, headers={"X-CSRF-Token": token}).status_code == 403
    assert path.read_bytes() == before and not note_path(path).exists()


def test_an_invalid_edit_is_refused_with_its_field_and_nothing_changes(hmi, rdir, cell, capsys, tmp_path):
    store, log = cell
    path = rdir / "bracket-a.yaml"
    before, active = path.read_bytes(), store.active["bracket-a"].hash
    bad = before.decode().replace("fiducial_radius_mm: 1.5", "fiducial_radius_mm: 0.1")
    assert bad != before.decode()
    c = client(hmi)
    login(c)
    token, sha = editor(c, "bracket-a")
    checked = c.post("/api/recipes/bracket-a/validate", json={"text": bad}, headers={"X-CSRF-Token": token}).json()
    r = c.post("/api/recipes/bracket-a/save", json={"text": bad, "base_sha256": sha}, headers={"X-CSRF-Token": token})
    assert r.status_code == 422
    [err] = r.json()["errors"]
    assert checked["errors"] == [err] and not checked["ok"]
    assert err["field"] == "part.fiducial_radius_mm" and "greater than 0.2" in err["message"]
    # the same check as `cellctl recipe validate`: the same line, field and message
    other = tmp_path / "other"
    other.mkdir()
    (other / "bracket-a.yaml").write_text(bad)
    assert main(["recipe", "--dir", str(other), "validate"]) == 2
    assert f"{other / 'bracket-a.yaml'}:{err['line']}: {err['field']}: {err['message']}" in capsys.readouterr().out
    assert path.read_bytes() == before and not note_path(path).exists()
    assert store.refresh() == [] and store.active["bracket-a"].hash == active


def test_a_saved_recipe_is_what_recipe_show_prints_and_is_audited_with_user_and_role(hmi, rdir, cell, capsys):
    store, log = cell
    path = rdir / "bracket-a.yaml"
    mode = stat.S_IMODE(os.stat(path).st_mode)
    text = path.read_text().replace("tolerance_mm: 0.08", "tolerance_mm: 0.09") + "# edited in the HMI: ü\n"
    c = client(hmi)
    login(c)
    token, sha = editor(c, "bracket-a")
    r = c.post("/api/recipes/bracket-a/save", json={"text": text, "base_sha256": sha}, headers={"X-CSRF-Token": token})
    assert r.status_code == 200 and r.json()["ok"]
    saved = r.json()["sha256"]
    assert main(["recipe", "--dir", str(rdir), "show", "bracket-a"]) == 0
    header, shown = capsys.readouterr().out.split("\n", 1)
    assert shown.encode() == text.encode() == path.read_bytes() and saved in header
    assert stat.S_IMODE(os.stat(path).st_mode) == mode
    assert [f.name for f in rdir.iterdir() if f.name.startswith(".") and f.is_file()] == []   # no temp file left
    dec = c.get(f"/api/recipes/bracket-a/decision?sha256={saved}").json()
    assert dec["state"] == "pending"
    [entry] = store.refresh()                          # the controller, between cycles
    assert entry.action == "activate" and store.active["bracket-a"].hash == saved
    row = log.audit_rows()[-1]
    assert row["action"] == "recipe_activate" and row["hash"] == saved
    assert row["who"].startswith("alice (maintenance, hmi; file owner ")
    assert log.audit_break() is None
    dec = c.get(f"/api/recipes/bracket-a/decision?sha256={saved}").json()
    assert dec["state"] == "active" and dec["audit"]["id"] == row["id"]
    # the editor still holds the old version: a second save is refused, nothing written
    r = c.post("/api/recipes/bracket-a/save", json={"text": text + "# again\n", "base_sha256": sha},
               headers={"X-CSRF-Token": token})
    assert r.status_code == 409 and path.read_text() == text


def test_reports_are_listed_and_nothing_outside_their_folder_is_served(hmi, tmp_path):
    reports = tmp_path / "reports"
    (reports / "gap-1").mkdir(parents=True)
    (reports / "gap-1" / "index.html").write_text("<h1>gap</h1>")
    (tmp_path / "secret.html").write_text("secret")
    (reports / "link.html").symlink_to(tmp_path / "secret.html")
    c = client(hmi)
    page = c.get("/reports").text
    assert "gap-1/index.html" in page and "link.html" not in page
    r = c.get("/reports/gap-1/index.html")
    assert r.status_code == 200 and "<h1>gap</h1>" in r.text and "sandbox" in r.headers["content-security-policy"]
    for bad in ("/reports/link.html", "/reports/../secret.html", "/reports/%2e%2e/secret.html"):
        assert c.get(bad).status_code == 404, bad


def test_passwd_adds_a_user_with_a_salted_hash_in_a_private_file(tmp_path, monkeypatch, capsys):
    import io
    users = tmp_path / "users.json"
    monkeypatch.setattr("sys.stdin", io.StringIO("s3cret-enough\n"))
    assert main(["hmi", "--users", str(users), "passwd", "bob", "--role", "engineer", "--password-stdin"]) == 0
    assert stat.S_IMODE(os.stat(users).st_mode) == 0o600
    doc = json.loads(users.read_text())
    assert doc["users"]["bob"]["role"] == "engineer" and "s3cret" not in users.read_text()
    assert doc["users"]["bob"]["password"].startswith("scrypt$")
    u = Users(users)
    assert u.authenticate("bob", "s3cret-enough")[:2] == ("bob", "engineer")
    assert u.authenticate("bob", "wrong") is None
    monkeypatch.setattr("sys.stdin", io.StringIO("short\n"))
    assert main(["hmi", "--users", str(users), "passwd", "eve", "--password-stdin"]) == 2
    assert "at least 8 characters" in capsys.readouterr().err


def test_failed_logins_slow_the_guesser_down_and_leave_the_user_alone_elsewhere(hmi, rdir, tmp_path):
    import dataclasses

    from cell.clock import ManualClock
    from cell.hmi.throttle import LoginThrottle
    clock = ManualClock(0.0)
    s = settings_from(None, str(tmp_path / "users.json"), str(tmp_path / "reports"), None, str(rdir),
                      str(tmp_path / "cell.sqlite"))
    app = create_app(dataclasses.replace(s, throttle=LoginThrottle(clock, free=3, base_s=1.0, cap_s=60.0)))
    c = client(app, host="10.0.0.66")
    for _ in range(3):
        assert login(c, password="guess guess").status_code == 401
    r = login(c)                                       # the right password, but too soon after 3 guesses
    assert r.status_code == 429 and "too many failed logins" in r.text and r.headers["retry-after"] == "1"
    assert login(client(app, host="10.0.0.9")).status_code == 303      # the user, from elsewhere: at once
    clock.advance(1.0)
    assert login(c, password="guess guess").status_code == 401       # a try after the wait, counted
    assert login(c).status_code == 429                                # the wait doubled
    clock.advance(2.0)
    assert login(c).status_code == 303


def test_hmi_refuses_a_port_in_use_naming_it(tmp_path, capsys):
    import socket
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        assert main(["hmi", "--users", str(tmp_path / "u.json"), "--port", str(port)]) == 2
    assert f"cannot listen on 127.0.0.1:{port}" in capsys.readouterr().err


def test_an_edit_the_controller_rejects_is_shown_rejected_with_its_reason_and_user(hmi, rdir, cell):
    """The HMI without --config cannot know the stations: the controller's own check (here:
    drives without SYNC support) refuses the saved version; the editor learns why."""
    from cell.recipes import motion_check
    _, log = cell
    store = RecipeStore(rdir, commit=log.record_recipe_changes, check=motion_check(False, [0.001] * 4))
    store.refresh()                                    # the controller, on drives without SYNC
    path = rdir / "bracket-a.yaml"
    active = store.active["bracket-a"].hash
    text = path.read_text().replace("sync: corrected", "sync: sync")
    assert "sync: sync" in text
    c = client(hmi)
    login(c)
    token, sha = editor(c, "bracket-a")
    saved = c.post("/api/recipes/bracket-a/save", json={"text": text, "base_sha256": sha},
                   headers={"X-CSRF-Token": token}).json()["sha256"]
    [entry] = store.refresh()
    assert entry.action == "reject" and store.active["bracket-a"].hash == active
    dec = c.get(f"/api/recipes/bracket-a/decision?sha256={saved}").json()
    assert dec["state"] == "rejected" and "motion.sync" in dec["audit"]["result"]
    assert dec["audit"]["who"].startswith("alice (maintenance, hmi")
