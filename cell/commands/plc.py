"""``cellctl plc``: set-up checks for the PLC link, for the engineer who installs a PLC.

    cellctl plc check-cert PLC.pem --config deploy/cell.yaml

``check-cert`` checks a PLC's client certificate for Modbus/TCP Security against the
config's ``plc.tls`` before the PLC is put on the line: in date, issued by a CA in
``plc.tls.ca``, carrying the role extension (OID 1.3.6.1.4.1.50316.802.1) with a role that
``plc.tls.roles`` lists; and the controller's own certificate, key and CA files. Prints the
role and its rights (exit 0); what is wrong, naming the field (exit 2).
"""
from __future__ import annotations

import argparse
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plc", help="PLC link set-up checks (Modbus/TCP Security certificates)")
    psub = p.add_subparsers(dest="plc_command", required=True, metavar="ACTION")
    c = psub.add_parser("check-cert", help="check a PLC's client certificate against plc.tls")
    c.add_argument("cert", help="the PLC's client certificate (PEM)")
    c.add_argument("--config", required=True, help="the cell config whose plc.tls section applies")
    c.set_defaults(func=run_check_cert)


def run_check_cert(args: argparse.Namespace) -> int:
    from cell.config import CellConfig
    from drivers.plc.tls import check_client_certificate, server_context
    tls = CellConfig.load(args.config).plc.tls
    server_context(Path(tls.cert), Path(tls.key), Path(tls.ca))
    role, rights = check_client_certificate(Path(args.cert), Path(tls.ca), tls.roles)
    state = "enabled" if tls.enabled else "not enabled (plc.tls.enabled: false)"
    print(f"{args.cert}: role {role!r}, rights: {', '.join(sorted(rights)) or 'read only'}; "
          f"controller certificate {tls.cert} fits its key; Modbus/TCP Security {state}")
    return 0
