"""Progress of a long command, on a terminal only.

A bar (tqdm) on stderr when stderr is a terminal; nothing at all otherwise, so output that is
piped, redirected or read by a program (``--json``) holds no bar, no carriage return and no
ANSI code. ``CELL_PROGRESS=0`` turns it off on a terminal too, ``CELL_PROGRESS=1`` forces it
(tests). tqdm is imported only when a bar is shown.

    with progress.bar("campaigns", total=200, unit="campaign") as p:
        for ...:
            p.update(1)          # or p.set(done, total) from a callback
"""
from __future__ import annotations

import os
import sys


def enabled(stream=None) -> bool:
    """Whether progress goes to ``stream`` (default stderr): a terminal, unless CELL_PROGRESS says."""
    forced = os.environ.get("CELL_PROGRESS", "").strip()
    if forced in ("0", "1"):
        return forced == "1"
    stream = sys.stderr if stream is None else stream
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError, OSError):    # closed or not a file
        return False


class _Off:
    """The bar when there is no terminal: every call does nothing."""

    def update(self, n: int = 1) -> None:
        pass

    def set(self, done: int, total: int | None = None) -> None:
        pass

    def note(self, text: str) -> None:
        pass

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class _Bar(_Off):
    def __init__(self, desc: str, total: int | None, unit: str, on: bool):
        from tqdm import tqdm
        # a terminal that reports no size (a serial console, a fresh pty) gets nothing from
        # tqdm, which takes 0 rows for "no room": draw 80 × 24 there
        try:
            size = os.get_terminal_size(sys.stderr.fileno())
            known = size.columns > 0 and size.lines > 0
        except (AttributeError, ValueError, OSError):
            known = False
        size = {"dynamic_ncols": True} if known else {"ncols": 80, "nrows": 24}
        self._bar = tqdm(total=total, desc=desc, unit=f" {unit}", file=sys.stderr, leave=False,
                         mininterval=0.2, disable=not on, **size)

    def update(self, n: int = 1) -> None:
        self._bar.update(n)

    def set(self, done: int, total: int | None = None) -> None:
        """Absolute progress (callbacks that report ``done, total``)."""
        if total is not None and total != self._bar.total:
            self._bar.total = total
        self._bar.update(done - self._bar.n)

    def note(self, text: str) -> None:
        """A short status after the counts (the last result, the step)."""
        self._bar.set_postfix_str(text, refresh=False)

    def close(self) -> None:
        self._bar.close()


def bar(desc: str, total: int | None = None, unit: str = "it"):
    """A progress bar for ``total`` units of work (None: a counter), shown only when
    :func:`enabled`. Use as a context manager; ``update(n)``, ``set(done, total)``, ``note``."""
    return _Bar(desc, total, unit, True) if enabled() else _Off()


def callback(p):
    """``progress(done, total)`` for the library functions that report that way."""
    return lambda done, total: p.set(done, total)


def each(items, desc: str, unit: str = "it"):
    """``items`` one at a time, with a bar on a terminal (loops of the benchmarks)."""
    items = items if hasattr(items, "__len__") else list(items)
    with bar(desc, len(items), unit) as p:
        for item in items:
            yield item
            p.update(1)
