"""``cellctl hmi``: the maintenance web app on this machine (default http://127.0.0.1:8080).

It shows the cell's status and last cycles live, the accuracy trend, the recipes (view,
diff against the active version, edit with validation as you type; saving needs a login
with an editing role, and the controller activates the edit between cycles and audits it
with that user and role) and the diagnosis reports under ``--reports``; with ``--line-dsn``,
the line view of every cell in the plant historian (``/line``). Requests must name
an allowed host (``--allowed-host``); behind a TLS proxy (``--trusted-proxy``, loopback by
default) the forwarded scheme and host are honoured.
``cellctl hmi passwd USER --role maintenance`` adds a user (or sets a new password).
"""
from __future__ import annotations

import argparse
import sys

from cell import paths
from cell.errors import ConfigError

DEFAULT_USERS = "var/hmi-users.json"
DEFAULT_REPORTS = "var/reports"
ROLES = ("maintenance", "engineer", "viewer")


def register(sub: argparse._SubParsersAction) -> None:
    from cell.commands import summary
    p = sub.add_parser("hmi", help="the maintenance web app (status, recipes, trend, reports)",
                       description=summary(__doc__))
    p.add_argument("--config", help="cell config (recipe folder, log, robot and stations for the "
                                    "recipe checks; default: the built-in simulated cell's)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1; "
                                                        "clients other than loopback must log in to see anything)")
    p.add_argument("--port", type=int, default=8080, help="TCP port (default 8080; 0 picks a free one)")
    p.add_argument("--users", default=str(paths.project(DEFAULT_USERS)),
                   help=f"users file (default: the project's {DEFAULT_USERS})")
    p.add_argument("--reports", default=str(paths.project(DEFAULT_REPORTS)),
                   help=f"folder of HTML reports (default: the project's {DEFAULT_REPORTS})")
    p.add_argument("--allowed-host", action="append", default=[], metavar="NAME",
                   help="a host name (or address) clients may use in the URL, besides the listen address, "
                        "localhost, 127.0.0.1 and [::1]; repeat for more (others get 400: DNS rebinding)")
    p.add_argument("--trusted-proxy", action="append", default=None, metavar="ADDR",
                   help="address (or network) of a TLS proxy whose X-Forwarded-Proto and X-Forwarded-Host "
                        "are honoured; repeat for more (default: loopback, 127.0.0.1 and ::1; 'none': no proxy)")
    p.add_argument("--plc", metavar="HOST:PORT", help="read the controller's status registers from this "
                                                      "Modbus TCP link (read-only); default: the log only")
    p.add_argument("--line-dsn", metavar="DSN", help="the plant historian's PostgreSQL: adds the line view "
                                                     "(/line, every cell of the plant); default: off")
    p.add_argument("--line-link", action="append", default=[], metavar="SITE/LINE/CELL=URL",
                   help="the line view links this cell to its own HMI at URL (its trend); repeat for more "
                        "(default: a page of the line view)")
    p.add_argument("--dir", help="recipe folder (default: the config's recipes.directory)")
    p.add_argument("--db", help="cycle log (default: the config's log.path)")
    hs = p.add_subparsers(dest="hmi_cmd", metavar="ACTION")
    pw = hs.add_parser("passwd", help="add a user or set a user's password and role")
    pw.add_argument("user")
    pw.add_argument("--role", choices=ROLES, default="maintenance", help="maintenance or engineer may edit "
                                                                          "recipes; viewer only looks (default maintenance)")
    pw.add_argument("--users", default=argparse.SUPPRESS,
                    help=f"users file (default: the project's {DEFAULT_USERS})")
    pw.add_argument("--password-stdin", action="store_true", help="read the password from stdin "
                                                                  "(default: ask twice on the terminal)")
    p.set_defaults(func=run)


def _plc(text: str | None) -> tuple[str, int] | None:
    if not text:
        return None
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ConfigError(f"--plc {text!r}: expected HOST:PORT, e.g. 127.0.0.1:5020")
    return host, int(port)


def run(args: argparse.Namespace) -> int:
    if args.hmi_cmd == "passwd":
        return _passwd(args)
    import ipaddress

    from cell.hmi.line import parse_links
    from cell.hmi.server import listen, serve, settings_from
    proxies = ("127.0.0.1", "::1") if args.trusted_proxy is None else \
        tuple(p for p in args.trusted_proxy if p.lower() != "none")
    settings = settings_from(args.config, args.users, args.reports, _plc(args.plc), args.dir, args.db,
                             listen_host=args.host, allowed_hosts=tuple(args.allowed_host), trusted_proxies=proxies,
                             line_dsn=args.line_dsn, line_links=parse_links(args.line_link))
    if not len(settings.users):
        print(f"cellctl hmi: no users in {args.users}: viewing only; add one with "
              "'cellctl hmi passwd USER --role maintenance'", file=sys.stderr)
    try:
        local = ipaddress.ip_address(args.host).is_loopback
    except ValueError:
        local = args.host == "localhost"
    if not local:
        print(f"cellctl hmi: listening on {args.host}: other machines can reach it over plain HTTP "
              "(passwords and sessions unencrypted); prefer 127.0.0.1 behind a TLS proxy. Clients must "
              f"name it as {args.host}, localhost or an --allowed-host", file=sys.stderr)
    sock = listen(args.host, args.port)
    host, port = sock.getsockname()[:2]
    url_host = f"[{host}]" if ":" in host else host
    print(f"cellctl hmi: serving http://{url_host}:{port}/ (recipes {settings.desk.directory}, "
          f"log {settings.log_path}); Ctrl-C stops", flush=True)
    if settings.line_dsn:
        print(f"cellctl hmi: line view at http://{url_host}:{port}/line", flush=True)
    serve(settings, sock)
    return 0


def _passwd(args: argparse.Namespace) -> int:
    import getpass

    from cell.hmi.users import set_user
    if args.password_stdin:
        password = sys.stdin.readline().rstrip("\n")
    else:
        password = getpass.getpass(f"password for {args.user}: ")
        if getpass.getpass("again: ") != password:
            raise ConfigError("the passwords differ; nothing changed")
    set_user(args.users, args.user, args.role, password)
    print(f"{args.users}: {args.user} ({args.role}) set")
    return 0
