"""The line view: every cell of the plant historian's PostgreSQL on one page.

Off unless the HMI is given the historian's DSN (``cellctl hmi --line-dsn``,
:attr:`~cell.hmi.app.HmiSettings.line_dsn`); then ``/line`` lists every cell the database
knows (online or offline from its retained status and Last Will, its state, last part,
the final error's p50/p95 in this shift and the one before, and what the historian knows
of its delivery: records received, watermark, records held above it, time since the last
record), polling ``/api/line`` every 2 s. A cell's name leads to its own HMI (its trend on
its status page) when ``--line-link CELL=URL`` names one, else to ``/line/cell?id=CELL``:
its trend and last cycles drawn from PostgreSQL. Figures and shifts:
:mod:`cell.plant.fleet`. Reads run in the HMI's ``reads`` pool; a database that cannot
answer is said on the page, not a 500.
"""
from __future__ import annotations

import io
from dataclasses import asdict
from typing import TYPE_CHECKING
from urllib.parse import quote

from starlette.requests import Request
from starlette.responses import JSONResponse, PlainTextResponse, Response
from starlette.routing import Route

if TYPE_CHECKING:
    from cell.hmi.app import Hmi


def line_rows(dsn: str, links: dict[str, str]) -> dict:
    """``/api/line``'s document: ``cells`` (each :class:`~cell.plant.fleet.CellLine` as a
    dict with ``state`` and ``href``) or ``error``."""
    from cell.plant import fleet
    try:
        lines = fleet.line_status(dsn)
    except fleet.FleetError as exc:
        return {"cells": [], "error": str(exc)}
    out = []
    for c in lines:
        row = asdict(c)
        row["state"] = c.state
        row["href"] = links.get(c.cell) or f"/line/cell?id={quote(c.cell, safe='/')}"
        out.append(row)
    return {"cells": out, "error": None,
            "shifts": ", ".join(f"{n} {h:02d}:00-{(h + fleet.SHIFT_H) % 24:02d}:00" for n, h in fleet.SHIFTS)}


def trend_png(dsn: str, cell: str) -> bytes | None:
    """The final and verify error of ``cell``'s last 500 cycles as a PNG; None without any."""
    from datetime import datetime

    from matplotlib.figure import Figure

    from cell.plant import fleet
    rows = [r for r in fleet.cell_cycles(dsn, cell) if r["status"] == "done"]
    if not rows:
        return None
    fig = Figure(figsize=(8, 3.6), dpi=100)
    ax = fig.add_subplot()
    t = [datetime.fromisoformat(r["finished_at"]) for r in rows]
    ax.plot(t, [r["final_error_mm"] for r in rows], ".-", label="final error")
    ax.plot(t, [r["verify_error_mm"] for r in rows], ".", label="verify error")
    ax.set_ylabel("mm")
    ax.set_title(f"{cell}: last {len(rows)} parts (plant historian)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small")
    fig.autofmt_xdate()
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


def routes(hmi: Hmi) -> list[Route]:
    """The line view's routes; none when the HMI has no ``line_dsn`` (the pages are 404)."""
    s = hmi.s
    if not s.line_dsn:
        return []
    dsn, links = s.line_dsn, dict(s.line_links)

    async def line(request: Request) -> Response:
        if (r := hmi.view_refusal(request)) is not None:
            return r
        return hmi.page(request, "line.html")

    async def api_line(request: Request) -> Response:
        if (r := hmi.view_refusal(request)) is not None:
            return r
        return JSONResponse(await hmi.reads.run(line_rows, dsn, links))

    def cell_page(cell: str) -> dict:
        from cell.plant import fleet
        try:
            return {"cycles": fleet.cell_cycles(dsn, cell, 20)[::-1], "error": None}
        except fleet.FleetError as exc:
            return {"cycles": [], "error": str(exc)}

    async def line_cell(request: Request) -> Response:
        if (r := hmi.view_refusal(request)) is not None:
            return r
        cell = request.query_params.get("id", "")
        doc = await hmi.reads.run(cell_page, cell)
        return hmi.page(request, "line_cell.html", cell=cell, status_code=200 if doc["cycles"] else 404, **doc)

    async def line_trend(request: Request) -> Response:
        if (r := hmi.view_refusal(request)) is not None:
            return r
        from cell.plant.fleet import FleetError
        try:
            png = await hmi.reads.run(trend_png, dsn, request.query_params.get("id", ""))
        except FleetError as exc:
            return PlainTextResponse(str(exc), status_code=503)
        if png is None:
            return PlainTextResponse("no cycles of this cell in the historian", status_code=404)
        return Response(png, media_type="image/png")

    return [Route("/line", line), Route("/api/line", api_line), Route("/line/cell", line_cell),
            Route("/line/trend.png", line_trend)]


def parse_links(given: list[str]) -> tuple[tuple[str, str], ...]:
    """``--line-link CELL=URL`` values as (cell id, URL) pairs; ConfigError unless the cell
    is ``site/line/cell`` and the URL is http(s) (a link on the page, never a script)."""
    from cell.errors import ConfigError
    from cell.plant.topics import CellTopics, TopicError
    out = []
    for text in given:
        cell, sep, url = text.partition("=")
        try:
            CellTopics.from_path(cell)
        except TopicError as exc:
            raise ConfigError(f"--line-link {text!r}: {exc}") from None
        if not sep or not url.lower().startswith(("http://", "https://")):
            raise ConfigError(f"--line-link {text!r}: expected SITE/LINE/CELL=http(s)://HOST:PORT/")
        out.append((cell, url))
    return tuple(out)
