"""Login throttling: failed logins slow guessing down without locking the real user out.

Two records count failed logins: one per (user name, client address) pair and one per
client address. After ``free`` failures of a record, the next attempt it covers must wait
``base_s``, and every further failure doubles the wait, up to ``cap_s`` (the client's own
record allows more failures, ``client_free``, as one address may be a proxy for several
people, and waits at most ``client_cap_s``). An attempt that comes too early is refused
unchecked, with the seconds to wait. Nothing is locked: a guesser only slows itself down,
and the real user logging in from another address is not affected by it at all.

Each attempt is *reserved* before its password is checked (:meth:`LoginThrottle.attempt`
counts it as a failure in the same step as it looks), so concurrent attempts cannot all
pass the look before any of them is counted. A successful login takes its reservation back
and clears its pair. Records idle for ``forget_s`` are forgotten.

Memory is bounded: a user name that cannot be one (:data:`cell.hmi.users.USER_NAME`) is
never stored (all such attempts share one record per client), the address is cut to 64
characters, and at most ``max_records`` records are kept (the least recently used go
first). Times come from ``clock`` (wall time in the product).
"""
from __future__ import annotations

import re
import threading
from collections import OrderedDict
from dataclasses import dataclass

from cell.hmi.users import USER_NAME

NOT_A_NAME = "\0not-a-user-name"      #: the one record key for names no user can have


@dataclass
class _Record:
    fails: int = 0
    last: float = 0.0                   #: clock time of the last failure counted


class LoginThrottle:
    """See the module doc. ``attempt`` → 0 (go on: check the password) or seconds to wait."""

    def __init__(self, clock=None, free: int = 3, base_s: float = 1.0, cap_s: float = 60.0,
                 client_free: int = 10, client_cap_s: float = 30.0, forget_s: float = 900.0,
                 max_records: int = 4096):
        from cell.clock import MonotonicClock
        self.clock = clock or MonotonicClock()
        self.free, self.base_s, self.cap_s = int(free), float(base_s), float(cap_s)
        self.client_free, self.client_cap_s = int(client_free), float(client_cap_s)
        self.forget_s, self.max_records = float(forget_s), int(max_records)
        self._records: OrderedDict[tuple, _Record] = OrderedDict()
        self._lock = threading.Lock()

    @staticmethod
    def user_key(name: str) -> str:
        """The record key of user name ``name``: itself, or one shared key for a name no
        user can have."""
        return name if re.match(USER_NAME, name) else NOT_A_NAME

    def _keys(self, user: str, client: str) -> tuple[tuple, tuple]:
        client = str(client)[:64]
        return ("pair", self.user_key(user), client), ("client", client)

    def _wait(self, key: tuple, rec: _Record, now: float) -> float:
        free, cap = (self.free, self.cap_s) if key[0] == "pair" else (self.client_free, self.client_cap_s)
        if rec.fails < free:
            return 0.0
        delay = min(cap, self.base_s * 2.0 ** min(rec.fails - free, 32))
        return max(0.0, rec.last + delay - now)

    def _get(self, key: tuple, now: float) -> _Record:
        rec = self._records.get(key)
        if rec is None or now - rec.last >= self.forget_s:
            rec = self._records[key] = _Record()
        self._records.move_to_end(key)
        return rec

    def attempt(self, user: str, client: str) -> float:
        """Reserve one login attempt of ``user`` from ``client``: 0.0 when its password may be
        checked now (it counts as a failure until :meth:`succeeded` says otherwise), else
        the seconds until it may be tried (nothing counted)."""
        now = self.clock.now()
        with self._lock:
            keys = self._keys(user, client)
            recs = [self._get(k, now) for k in keys]
            wait = max(self._wait(k, r, now) for k, r in zip(keys, recs))
            if wait <= 0:
                for r in recs:
                    r.fails += 1
                    r.last = now
            while len(self._records) > self.max_records:
                self._records.popitem(last=False)
            return wait

    def succeeded(self, user: str, client: str) -> None:
        """The reserved attempt logged in: its pair is cleared, the client's reservation
        taken back."""
        pair, client_key = self._keys(user, client)
        with self._lock:
            self._records.pop(pair, None)
            self._take_back(client_key)

    def _take_back(self, key: tuple) -> None:
        rec = self._records.get(key)
        if rec is not None and rec.fails > 0:
            rec.fails -= 1

    def __len__(self) -> int:
        """Records kept now (at most ``max_records``)."""
        return len(self._records)

    def keys(self) -> list[tuple]:
        """The records' keys, ``("pair", user, client)`` or ``("client", client)``."""
        with self._lock:
            return list(self._records)
