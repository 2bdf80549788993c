"""``cellctl historian``: take every cell's cycle records from the MQTT broker into PostgreSQL.

It subscribes to ``+/+/+/cycle`` and ``+/+/+/event`` (``--cells`` narrows both) with a
persistent session, commits each batch to the database named by ``--dsn`` (or
``CELL_HISTORIAN_DSN``), acknowledges a record or event to the broker only once it is
committed, and publishes each cell's watermark, retained, on
``<site>/<line>/<cell>/watermark``: the cells send again what it does not cover. Beside it,
each cell's retained status (online with its state, or its Last Will) goes to the table
``cell_status`` (:mod:`cell.plant.status`). It migrates its own tables at start.
Against the plant's broker (``deploy/mosquitto/``) it connects over TLS (``--tls``,
``--ca-file``) and logs in (``--username``, by default ``historian``, the ACL's name for it,
and ``--password-file``). Runs until SIGINT or SIGTERM (or ``--seconds``); what is not
committed then stays with the broker. Topic tree and payloads: ``cell/plant.md``.
"""
from __future__ import annotations

import argparse
import os
import sys

from cell.errors import ConfigError
from cell.shutdown import StopRequest

DSN_ENV = "CELL_HISTORIAN_DSN"


def register(sub: argparse._SubParsersAction) -> None:
    from cell.commands import summary
    p = sub.add_parser("historian", help="cycle records from the MQTT broker into PostgreSQL (plant historian)",
                       description=summary(__doc__))
    p.add_argument("--broker", default="127.0.0.1:1883", metavar="HOST:PORT",
                   help="the MQTT broker (default 127.0.0.1:1883)")
    p.add_argument("--dsn", help=f"PostgreSQL connection string (default: ${DSN_ENV})")
    p.add_argument("--cells", default="+/+/+", metavar="SITE/LINE/CELL",
                   help="whose records, events and status to take, '+' for any one level (default +/+/+: every cell)")
    p.add_argument("--client-id", default="plant-historian",
                   help="MQTT client id: the broker keeps this id's session (default plant-historian)")
    p.add_argument("--session-expiry-s", type=int, default=7 * 24 * 3600,
                   help="how long the broker keeps records for a historian that is away (default 7 days)")
    p.add_argument("--tls", action="store_true", help="connect over TLS, checking the broker's certificate")
    p.add_argument("--ca-file", metavar="PEM", help="the CA that signed the broker's certificate "
                   "(default: the system's); implies --tls")
    p.add_argument("--password-file", metavar="FILE",
                   help="log in with the password this file holds (readable by the historian's user only)")
    p.add_argument("--username", default="historian",
                   help="the login with --password-file (default historian, the name deploy/mosquitto/plant.acl uses)")
    p.add_argument("--seconds", type=float, help="stop after this many seconds (default: run until signalled)")
    p.set_defaults(func=run)


def _broker(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ConfigError(f"--broker {text!r} is not HOST:PORT")
    return host, int(port)


def _security(args: argparse.Namespace):
    from cell.plant.mqtt import Security, read_password
    if not (args.tls or args.ca_file or args.password_file):
        return None
    password = read_password(args.password_file, "--password-file") if args.password_file else None
    return Security(tls=bool(args.tls or args.ca_file), ca_file=args.ca_file,
                    username=args.username if password is not None else None, password=password)


def run(args: argparse.Namespace) -> int:
    from cell.plant.historian import Historian, HistorianSettings
    from cell.plant.status import StatusRecorder
    from cell.plant.topics import TopicError, subscription

    host, port = _broker(args.broker)
    dsn = args.dsn or os.environ.get(DSN_ENV)
    if not dsn:
        raise ConfigError(f"historian: give --dsn or set {DSN_ENV}")
    parts = args.cells.split("/")
    if len(parts) != 3:
        raise ConfigError(f"--cells {args.cells!r} is not SITE/LINE/CELL")
    try:
        topic_filter = subscription("cycle", *parts)
        event_filter = subscription("event", *parts)
        status_filter = subscription("status", *parts)
    except TopicError as exc:
        raise ConfigError(f"--cells: {exc}") from None
    security = _security(args)
    historian = Historian(HistorianSettings(host, port, dsn, client_id=args.client_id, topic_filter=topic_filter,
                                            event_filter=event_filter,
                                            session_expiry_s=args.session_expiry_s, security=security))
    status = StatusRecorder(host, port, dsn, client_id=f"{args.client_id}-status", topic_filter=status_filter,
                            security=security)
    stop = StopRequest().install()               # a handler without locks (cell/shutdown.py)
    historian.start()
    status.start()
    print(f"historian taking {topic_filter} from {host}:{port}; Ctrl-C to stop", flush=True)
    try:
        stop.wait(args.seconds)
    finally:
        status.stop()
        historian.stop()
        print(f"historian stopped: {historian.received} received, {historian.inserted} written, "
              f"{historian.duplicates} duplicate(s), {historian.rejected} refused", file=sys.stderr, flush=True)
    return 0
