"""The fleet as the plant historian's PostgreSQL knows it: accuracy per cell, recipe and
shift (``cellctl fleet report``), and each cell's line status (the HMI's line view).

**Shifts** are three 8-hour shifts in UTC (:data:`SHIFTS`): ``early`` 06:00-14:00,
``late`` 14:00-22:00, ``night`` 22:00-06:00. A night shift belongs to the date it starts on
(a cycle at 03:00 UTC on the 28th is in the night shift of the 27th). A cycle is placed by
its ``finished_at``. UTC, not local time: one plant's cells may sit in different time
zones, and the table must not change with the reader's.

**Figures** per group: ``parts`` (cycles done), ``faults`` (cycles ended by a fault),
``aborted``, and the 50th and 95th percentiles (numpy's linear interpolation) of the
final error (``final_error_mm``, after compensation) and of the verify error
(``verify_error_mm``, the independent check) over the done cycles that have one, in mm.

**What the historian can know of a cell's delivery** (:func:`line_status`): for the log the
cell sends now (its status's ``log_id``, else the log of its last record), the records
received, the highest id received, the watermark (every record up to it committed) and
the records held above it (received, waiting for one still missing below them), and the
time since the last record arrived. The cell's own backlog (rows it has not sent yet) is
only the cell's to know (its health report, ``cell/plant/outbox.py``).

Errors a reader can act on raise :class:`FleetError` (a :class:`~cell.errors.CellError`:
``cellctl`` exits 2): the database unreachable, no historian tables in it, no records.
psycopg and numpy are imported when used.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from datetime import date, datetime, timedelta, timezone

from cell.errors import CellError

#: (name, start hour UTC): three 8-hour shifts; the night shift runs past midnight
SHIFTS: tuple[tuple[str, int], ...] = (("early", 6), ("late", 14), ("night", 22))
SHIFT_H = 8


class FleetError(CellError):
    """The historian's database cannot answer: unreachable, not a historian's, or empty."""


def shift_of(t: datetime) -> tuple[date, str]:
    """(the date the shift started on, its name) of the moment ``t`` (aware, any zone)."""
    t = t.astimezone(timezone.utc)
    first = SHIFTS[0][1]
    shifted = t - timedelta(hours=first)          # shifts now start at 0, 8, 16 from this date
    k = shifted.hour // SHIFT_H
    return shifted.date(), SHIFTS[k][0]


def shift_start(day: date, name: str) -> datetime:
    """The UTC start of shift ``name`` of ``day``."""
    hour = dict(SHIFTS)[name]
    return datetime(day.year, day.month, day.day, tzinfo=timezone.utc) + timedelta(hours=hour)


def shift_label(day: date, name: str) -> str:
    start = shift_start(day, name)
    end = start + timedelta(hours=SHIFT_H)
    return f"{day.isoformat()} {name} {start:%H:%M}-{end:%H:%M} UTC"


# ---------------------------------------------------------------------------- reading
@dataclass(frozen=True)
class Cycle:
    """One cycle record as the fleet figures need it."""

    cell: str
    recipe: str
    status: str
    fault_code: int
    finished_at: datetime
    final_error_mm: float | None
    verify_error_mm: float | None


def connect(dsn: str):
    """A read connection to the historian's database; raises :class:`FleetError`."""
    import psycopg
    try:
        return psycopg.connect(dsn, autocommit=True, connect_timeout=5)
    except psycopg.Error as exc:
        raise FleetError(f"cannot reach the historian's database ({_shown(dsn)}): "
                         f"{str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__}") from None


def _shown(dsn: str) -> str:
    """The DSN without a password."""
    return " ".join(p for p in dsn.split() if not p.lower().startswith("password="))


def _require_tables(db, dsn: str) -> None:
    if db.execute("SELECT to_regclass('cycles')").fetchone()[0] is None:
        raise FleetError(f"no historian tables in the database ({_shown(dsn)}): has `cellctl historian "
                         "--dsn` written to it?")


def read_cycles(dsn: str, since: datetime | None = None, cells: str | None = None) -> list[Cycle]:
    """The cycle records (of ``cells``, a SQL LIKE pattern on ``site/line/cell``; finished at
    or after ``since``), oldest first. Raises :class:`FleetError` if there are none."""
    with connect(dsn) as db:
        _require_tables(db, dsn)
        sql = ("SELECT cell, recipe, status, fault_code, finished_at::timestamptz, final_error_mm,"
               " (record->>'verify_error_mm')::double precision FROM cycles WHERE true")
        args: list = []
        if since is not None:
            sql += " AND finished_at::timestamptz >= %s"
            args.append(since)
        if cells:
            sql += " AND cell LIKE %s"
            args.append(cells)
        rows = db.execute(sql + " ORDER BY finished_at::timestamptz, cell", args).fetchall()
    if not rows:
        what = " matching the filter" if since is not None or cells else ""
        raise FleetError(f"no cycle records{what} in the historian's database ({_shown(dsn)})")
    return [Cycle(*r) for r in rows]


# ---------------------------------------------------------------------------- figures
@dataclass(frozen=True)
class Group:
    """The figures of one (cell, recipe, shift) group; ``None``: no value to take it from."""

    cell: str
    recipe: str
    shift: str                     #: shift_label()
    shift_start: str               #: ISO 8601 UTC
    parts: int
    faults: int
    aborted: int
    final_p50_mm: float | None
    final_p95_mm: float | None
    verify_p50_mm: float | None
    verify_p95_mm: float | None


def _pcts(values: list[float]) -> tuple[float | None, float | None]:
    if not values:
        return None, None
    import numpy as np
    p50, p95 = np.percentile(np.asarray(values, dtype=float), [50, 95])
    return float(p50), float(p95)


def summarise(cycles: list[Cycle], by_recipe: bool = True) -> list[Group]:
    """Figures per cell, recipe (or ``*`` for all when not ``by_recipe``) and shift, in the
    order cell, shift start, recipe."""
    groups: dict[tuple, list[Cycle]] = {}
    for c in cycles:
        day, name = shift_of(c.finished_at)
        groups.setdefault((c.cell, shift_start(day, name), day, name, c.recipe if by_recipe else "*"), []).append(c)
    out = []
    for (cell, start, day, name, recipe), cs in sorted(groups.items(), key=lambda kv: kv[0][:2] + kv[0][4:]):
        done = [c for c in cs if c.status == "done"]
        fin = _pcts([c.final_error_mm for c in done if c.final_error_mm is not None])
        ver = _pcts([c.verify_error_mm for c in done if c.verify_error_mm is not None])
        out.append(Group(cell, recipe, shift_label(day, name), start.isoformat(), len(done),
                         sum(c.status == "fault" for c in cs), sum(c.status == "aborted" for c in cs),
                         *fin, *ver))
    return out


def _mm(v: float | None) -> str:
    return "–" if v is None else f"{v:.4f}"


def markdown(groups: list[Group]) -> str:
    """The groups as one Markdown table (errors in mm, 4 decimals: 0.1 µm)."""
    lines = ["| cell | recipe | shift (UTC) | parts | faults | aborted | final p50 mm | final p95 mm "
             "| verify p50 mm | verify p95 mm |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for g in groups:
        lines.append(f"| {g.cell} | {g.recipe} | {g.shift} | {g.parts} | {g.faults} | {g.aborted} | "
                     f"{_mm(g.final_p50_mm)} | {_mm(g.final_p95_mm)} | {_mm(g.verify_p50_mm)} | "
                     f"{_mm(g.verify_p95_mm)} |")
    return "\n".join(lines)


def to_json(groups: list[Group]) -> str:
    doc = {"shifts": {name: f"{h:02d}:00-{(h + SHIFT_H) % 24:02d}:00 UTC" for name, h in SHIFTS},
           "units": {"errors": "mm"}, "groups": [asdict(g) for g in groups]}
    return json.dumps(doc, indent=2)


def figure(groups: list[Group], title: str = "final error per shift (p50 solid, p95 dashed)"):
    """A matplotlib Figure: per cell, the final error's p50 and p95 per shift (all recipes
    of the groups given), against the shift's start."""
    from matplotlib.figure import Figure
    fig = Figure(figsize=(9, 4.5), dpi=100)
    ax = fig.add_subplot()
    cells = sorted({g.cell for g in groups})
    for k, cell in enumerate(cells):
        gs = [g for g in groups if g.cell == cell and g.final_p50_mm is not None]
        if not gs:
            continue
        x = [datetime.fromisoformat(g.shift_start) for g in gs]
        colour = f"C{k % 10}"
        ax.plot(x, [g.final_p50_mm for g in gs], "o-", color=colour, label=f"{cell} p50")
        ax.plot(x, [g.final_p95_mm for g in gs], "s--", color=colour, label=f"{cell} p95")
    ax.set_ylabel("final error, mm")
    ax.set_xlabel("shift start (UTC)")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    if ax.lines:
        ax.legend(fontsize="small")
    fig.autofmt_xdate()
    fig.tight_layout()
    return fig


# ---------------------------------------------------------------------------- the line
@dataclass(frozen=True)
class CellLine:
    """One cell's line status (module doc: what the historian can know)."""

    cell: str
    online: bool | None            #: None: no status heard from it
    status_since: str | None       #: when online last changed (ISO, UTC)
    cell_state: str | None         #: the state machine's state in its status (None: not said)
    fault_code: int | None         #: its fault code then (0: none)
    fault_text: str | None
    session: int | None
    log_id: str | None
    last_part: int | None
    last_recipe: str | None
    last_outcome: str | None       #: done, fault or aborted
    last_fault: str | None         #: "code: text" of a last cycle that faulted
    last_finished_at: str | None
    received: int                  #: records of log_id in the database
    highest_id: int | None
    watermark: int | None
    held_above: int                #: records received above the watermark
    last_received_at: str | None
    since_last_record_s: float | None
    shifts: list[dict]             #: this shift and the one before: label, parts, faults, p50, p95

    @property
    def state(self) -> str:
        """In words: offline, not heard from, or online with its state (and fault) when its
        status says them, else with the last cycle's outcome."""
        if self.online is None:
            return "no status heard"
        if not self.online:
            return "offline"
        if self.cell_state is not None:
            if not self.fault_code:
                return f"online, {self.cell_state}"
            fault = f"fault {self.fault_code}" + (f": {self.fault_text}" if self.fault_text else "")
            return f"online, {fault}" if self.cell_state == "fault" else f"online, {self.cell_state} ({fault})"
        if self.last_outcome == "fault":
            return "online, last cycle faulted"
        return "online" if self.last_outcome is None else f"online, last cycle {self.last_outcome}"


def line_status(dsn: str, now: datetime | None = None) -> list[CellLine]:
    """Every cell the database knows (from its records or its status), by id; raises
    :class:`FleetError` when the database is unreachable or has no historian tables."""
    now = now or datetime.now(timezone.utc)
    day, name = shift_of(now)
    this_start = shift_start(day, name)
    prev_start = this_start - timedelta(hours=SHIFT_H)
    with connect(dsn) as db:
        _require_tables(db, dsn)
        has_status = db.execute("SELECT to_regclass('cell_status')").fetchone()[0] is not None
        with_state = has_status and db.execute(      # migration 4: a status's state
            "SELECT count(*) FROM information_schema.columns WHERE table_name = 'cell_status'"
            " AND column_name = 'state'").fetchone()[0] > 0
        state_cols = "state, fault_code, fault_text" if with_state else "NULL, NULL, NULL"
        status = {r[0]: r[1:] for r in db.execute(
            f"SELECT cell, online, changed_at, session, log_id, {state_cols} FROM cell_status")} if has_status else {}
        latest_log = dict(db.execute("SELECT DISTINCT ON (cell) cell, log_id FROM cycles"
                                     " ORDER BY cell, received_at DESC, cycle_id DESC").fetchall())
        recent = [Cycle(*r) for r in db.execute(
            "SELECT cell, recipe, status, fault_code, finished_at::timestamptz, final_error_mm,"
            " (record->>'verify_error_mm')::double precision FROM cycles"
            " WHERE finished_at::timestamptz >= %s", (prev_start,))]
        out = []
        for cell in sorted(set(status) | set(latest_log)):
            online, changed, session, status_log, cell_state, fault_code, fault_text = status.get(cell, (None,) * 7)
            log_id = status_log or latest_log.get(cell)
            received, highest, last_at = db.execute(
                "SELECT count(*), max(cycle_id), max(received_at) FROM cycles WHERE cell = %s AND log_id = %s",
                (cell, log_id)).fetchone()
            wm = db.execute("SELECT cycle_id FROM watermarks WHERE cell = %s AND log_id = %s",
                            (cell, log_id)).fetchone()
            wm = None if wm is None else int(wm[0])
            held = db.execute("SELECT count(*) FROM cycles WHERE cell = %s AND log_id = %s AND cycle_id > %s",
                              (cell, log_id, wm or 0)).fetchone()[0]
            last = db.execute("SELECT part_id, recipe, status, fault_code, record->>'fault_text', finished_at"
                              " FROM cycles WHERE cell = %s ORDER BY finished_at::timestamptz DESC, cycle_id DESC"
                              " LIMIT 1", (cell,)).fetchone()
            shifts = []
            for g in summarise([c for c in recent if c.cell == cell], by_recipe=False):
                shifts.append({"shift": g.shift, "current": g.shift_start == this_start.isoformat(),
                               "parts": g.parts, "faults": g.faults, "final_p50_mm": g.final_p50_mm,
                               "final_p95_mm": g.final_p95_mm})
            out.append(CellLine(
                cell=cell, online=online, status_since=changed.isoformat() if changed else None,
                cell_state=cell_state, fault_code=fault_code, fault_text=fault_text, session=session,
                log_id=log_id, last_part=last[0] if last else None, last_recipe=last[1] if last else None,
                last_outcome=last[2] if last else None,
                last_fault=f"{last[3]}: {last[4] or ''}".strip(": ") if last and last[2] == "fault" else None,
                last_finished_at=last[5] if last else None, received=int(received), highest_id=highest,
                watermark=wm, held_above=int(held), last_received_at=last_at.isoformat() if last_at else None,
                since_last_record_s=(now - last_at).total_seconds() if last_at else None, shifts=shifts))
    return out


def cell_cycles(dsn: str, cell: str, limit: int = 500) -> list[dict]:
    """The last ``limit`` cycle records of ``cell``, oldest first (for its trend)."""
    with connect(dsn) as db:
        _require_tables(db, dsn)
        rows = db.execute("SELECT cycle_id, part_id, recipe, status, finished_at, final_error_mm,"
                          " (record->>'verify_error_mm')::double precision FROM cycles WHERE cell = %s"
                          " ORDER BY finished_at::timestamptz DESC, cycle_id DESC LIMIT %s",
                          (cell, limit)).fetchall()
    keys = ("cycle_id", "part_id", "recipe", "status", "finished_at", "final_error_mm", "verify_error_mm")
    return [dict(zip(keys, r)) for r in reversed(rows)]
