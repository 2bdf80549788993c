"""The HMI's defences that need no network (Starlette's in-process client against the real
app): sessions that end, the users file read again, trusted hosts and proxies, response
headers, temporary files a planted symlink cannot redirect, and a login throttle whose
memory stays bounded. Network-level attacks are in ``tests/system/test_hmi_attacks.py``."""
from __future__ import annotations

import dataclasses
import gc
import io
import json
import os
import tracemalloc

import pytest
from starlette.testclient import TestClient

from cell.cli import main
from cell.clock import ManualClock
from cell.hmi.app import create_app
from cell.hmi.server import settings_from
from cell.hmi.users import set_user
from cell.recipes.notes import note_path
from tests.cell.test_hmi import PASSWORD, cell, client, csrf, editor, hmi, login  # noqa: F401 -- fixtures

REMOTE = "192.168.10.77"


def settings(rdir, tmp_path, **kw):
    s = settings_from(None, str(tmp_path / "users.json"), str(tmp_path / "reports"), None, str(rdir),
                      str(tmp_path / "cell.sqlite"))
    return dataclasses.replace(s, **kw)


# ---------------------------------------------------------------------------- sessions
def test_logout_ends_the_session_so_a_copied_cookie_no_longer_works(hmi):
    alice = client(hmi, host=REMOTE)
    assert login(alice).status_code == 303
    copied = client(hmi, host=REMOTE)
    copied.cookies.set("cell_hmi", alice.cookies["cell_hmi"])
    assert copied.get("/api/status").status_code == 200
    assert alice.post("/logout", data={"csrf": csrf(alice, "/")}, follow_redirects=False).status_code == 303
    assert copied.get("/api/status").status_code == 401
    assert copied.post("/api/recipes/bracket-a/save", json={"text": ""},
                       headers={"X-CSRF-Token": "x"}).status_code in (401, 403)


def test_passwd_takes_effect_at_once_and_ends_the_users_sessions(hmi, tmp_path, monkeypatch):
    alice = client(hmi, host=REMOTE)
    assert login(alice).status_code == 303 and alice.get("/api/status").status_code == 200
    monkeypatch.setattr("sys.stdin", io.StringIO("a new password\n"))
    assert main(["hmi", "--users", str(tmp_path / "users.json"), "passwd", "alice", "--password-stdin"]) == 0
    assert alice.get("/api/status").status_code == 401                      # her session ended
    other = client(hmi, host=REMOTE)
    assert login(other).status_code == 401                                  # the old password: refused
    assert login(other, password="a new password").status_code == 303       # no restart needed
    assert "alice (maintenance)" in other.get("/").text


def test_a_damaged_users_file_logs_everyone_out_until_fixed(hmi, tmp_path):
    alice = client(hmi, host=REMOTE)
    assert login(alice).status_code == 303
    users = tmp_path / "users.json"
    good = users.read_text()
    users.write_text("{not json")
    assert alice.get("/api/status").status_code == 401
    page = client(hmi).get("/login").text
    assert "not a JSON users file" in page
    users.write_text(good)
    assert login(client(hmi, host=REMOTE)).status_code == 303


# ---------------------------------------------------------------------------- hosts and proxies
def test_a_request_naming_another_host_is_refused(rdir, tmp_path, hmi):
    for base in ("http://evil.example:8080", "http://192.168.10.5:8080"):
        r = TestClient(hmi, base_url=base, client=("127.0.0.1", 5000)).get("/")
        assert r.status_code == 400 and "--allowed-host" in r.text, base
    for base in ("http://127.0.0.1:8080", "http://localhost:8080", "http://[::1]:8080"):
        assert TestClient(hmi, base_url=base, client=("127.0.0.1", 5000)).get("/").status_code == 200, base
    # DNS rebinding cannot name a good host in a forwarded header either
    r = TestClient(hmi, base_url="http://evil.example:8080", client=("127.0.0.1", 5000)).get(
        "/", headers={"X-Forwarded-Host": "localhost"})
    assert r.status_code == 400
    named = create_app(settings(rdir, tmp_path, allowed_hosts=("hmi.plant.example",)))
    named_client = TestClient(named, base_url="http://hmi.plant.example", client=("127.0.0.1", 5000))
    assert named_client.get("/").status_code == 200


def test_behind_a_tls_proxy_posts_compare_the_origin_with_the_forwarded_scheme(rdir, tmp_path, hmi):
    app = create_app(settings(rdir, tmp_path, allowed_hosts=("hmi.plant.example",)))
    fwd = {"X-Forwarded-Proto": "https", "Origin": "https://hmi.plant.example"}
    proxy = TestClient(app, base_url="http://hmi.plant.example", client=("127.0.0.1", 40000), headers=fwd)
    r = proxy.post("/login", data={"csrf": csrf(proxy), "user": "alice", "password": PASSWORD},
                   follow_redirects=False)
    assert r.status_code == 303
    token, sha = editor(proxy, "bracket-a")
    r = proxy.post("/api/recipes/bracket-a/validate", json={"text": "x: 1"}, headers={"X-CSRF-Token": token})
    assert r.status_code == 200
    # a client that is not a trusted proxy cannot claim https
    direct = TestClient(app, base_url="http://hmi.plant.example", client=("10.1.2.3", 40000), headers=fwd)
    r = direct.post("/login", data={"csrf": csrf(direct), "user": "alice", "password": PASSWORD},
                    follow_redirects=False)
    assert r.status_code == 403 and "cross-site" in r.text


# ---------------------------------------------------------------------------- headers and bodies
def test_every_answer_is_not_cached_and_keeps_its_referrer(hmi):
    c = client(hmi)
    token = csrf(c, "/")
    answers = [c.get(p) for p in ("/", "/recipes", "/recipes/bracket-a", "/reports", "/api/status", "/login",
                                  "/trend.png", "/recipes/nope", "/api/recipes/bracket-a/decision?sha256=00")]
    answers.append(c.post("/api/recipes/bracket-a/validate", json={"text": "x: 1"}, headers={"X-CSRF-Token": token}))
    answers.append(c.post("/logout", data={"csrf": "forged"}))
    for r in answers:
        assert r.headers["cache-control"] == "no-store", r.url
        assert r.headers["referrer-policy"] == "same-origin", r.url
    static = c.get("/static/hmi.css")
    assert static.headers["referrer-policy"] == "same-origin"
    assert "no-store" not in static.headers.get("cache-control", "")


def test_bodies_are_refused_by_size_and_type_before_they_are_read(hmi):
    c = client(hmi)
    token = csrf(c, "/")
    big = c.post("/api/recipes/bracket-a/validate", content=b"{}", headers={
        "X-CSRF-Token": token, "Content-Type": "application/json", "Content-Length": str(10 << 20)})
    assert big.status_code == 413 and big.headers["connection"] == "close"
    multi = c.post("/logout", files={"f": ("a.bin", b"x" * 100)}, data={"csrf": token})
    assert multi.status_code == 415
    form = c.post("/api/recipes/bracket-a/validate", data={"text": "x"}, headers={"X-CSRF-Token": token})
    assert form.status_code == 415
    assert c.post("/login", data={"csrf": token, "user": "alice", "password": "p" * 9000}).status_code == 413


# ---------------------------------------------------------------------------- temporary files
def test_symlinks_planted_in_the_folders_do_not_redirect_a_save(hmi, rdir, tmp_path):
    outside = tmp_path / "outside.txt"
    outside.write_text("untouched\n")
    pid = os.getpid()
    (rdir / ".edits").mkdir()
    links = [rdir / f".bracket-a.yaml.hmi-{pid}.tmp", rdir / ".edits" / f".bracket-a.yaml.json.{pid}.tmp",
             tmp_path / f".users.json.{pid}.tmp"]
    for link in links:                                # the predictable names of temporary files
        link.symlink_to(outside)
    c = client(hmi)
    login(c)
    token, sha = editor(c, "bracket-a")
    path = rdir / "bracket-a.yaml"
    text = path.read_text().replace("tolerance_mm: 0.08", "tolerance_mm: 0.09")
    r = c.post("/api/recipes/bracket-a/save", json={"text": text, "base_sha256": sha}, headers={"X-CSRF-Token": token})
    assert r.status_code == 200 and path.read_text() == text
    assert not note_path(path).is_symlink() and json.loads(note_path(path).read_text())["user"] == "alice"
    set_user(tmp_path / "users.json", "bob", "viewer", PASSWORD)
    assert not (tmp_path / "users.json").is_symlink()
    assert outside.read_text() == "untouched\n"
    # the notes folder itself a link elsewhere: refused, nothing written anywhere
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    for f in (rdir / ".edits").iterdir():
        f.unlink()
    (rdir / ".edits").rmdir()
    (rdir / ".edits").symlink_to(elsewhere)
    token, sha = editor(c, "bracket-a")
    r = c.post("/api/recipes/bracket-a/save", json={"text": text + "# again\n", "base_sha256": sha},
               headers={"X-CSRF-Token": token})
    assert r.status_code == 500 and path.read_text() == text
    assert list(elsewhere.iterdir()) == []
    assert sorted(p.name for p in rdir.iterdir() if p.name.startswith(".") and p.name != ".edits") == \
        sorted(p.name for p in links[:1])                                  # no temporary file of ours left


# ---------------------------------------------------------------------------- login throttle memory
@pytest.mark.slow
def test_failed_names_that_cannot_be_user_names_are_not_kept(rdir, tmp_path, hmi):
    from cell.hmi.throttle import LoginThrottle
    throttle = LoginThrottle(ManualClock(0.0))
    app = create_app(settings(rdir, tmp_path, throttle=throttle))
    tracemalloc.start()
    try:
        gc.collect()
        before = tracemalloc.get_traced_memory()[0]
        for i in range(400):
            c = client(app, host=f"10.9.{i // 200}.{i % 200 + 1}")
            assert login(c, user=f"{i:04d}" + "x" * 6000, password="guess guess").status_code == 401
            del c
        gc.collect()
        kept = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert kept < 1 << 20, f"{kept} bytes kept after 400 failed logins with 6 KB names"
    assert all(len(k[1]) <= 40 for k in throttle.keys() if k[0] == "pair")


def test_the_throttle_keeps_a_bounded_number_of_records():
    from cell.hmi.throttle import LoginThrottle
    throttle = LoginThrottle(ManualClock(0.0), max_records=500)
    for i in range(10_000):
        throttle.attempt("alice", f"10.{i // 65536}.{i // 256 % 256}.{i % 256}")
    assert len(throttle) == 500


def test_a_trusted_proxy_that_is_no_address_is_refused_naming_it(tmp_path, capsys):
    assert main(["hmi", "--users", str(tmp_path / "u.json"), "--port", "0", "--trusted-proxy", "proxy.example"]) == 2
    assert "--trusted-proxy 'proxy.example'" in capsys.readouterr().err


def test_a_users_file_with_a_mistyped_key_is_named_in_our_words(tmp_path):
    import json

    from cell.errors import ConfigError
    from cell.hmi.users import load
    path = tmp_path / "users.json"
    path.write_text(json.dumps({"format": "cell-hmi-users/1",
                                "users": {"al": {"role": "viewer", "pasword": "x"}}}))
    with pytest.raises(ConfigError) as exc:
        load(path)
    assert str(exc.value).startswith(f"{path}: users.al.")
    assert "Field required" not in str(exc.value) and "Extra inputs" not in str(exc.value)
