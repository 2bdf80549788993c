"""A TCP proxy on loopback that can cut a link the way a network does: :class:`NetCut`.

It stands between one client (a cell) and its server (the broker): the client connects to
``127.0.0.1:port`` and every byte is passed on to the upstream address. A cut has two
phases, as a dying switch or a pulled cable under a firewall gives them:

* :meth:`NetCut.swallow`: bytes are read from both sides and dropped, and a new
  connection is accepted and its bytes dropped too; neither end learns anything (TCP
  acknowledges what it sent, nothing comes back);
* :meth:`NetCut.reset`: every connection is closed with an RST (``SO_LINGER`` 0) on both
  sides, and the proxy passes bytes again from then on.

One thread (``netcut``) does everything with a selector, so a reset closes each socket in
the thread that owns it (a socket closed under another thread's ``recv`` is neither
woken nor reset on Linux).
"""
from __future__ import annotations

import queue
import selectors
import socket
import struct
import threading


class NetCut:
    """A proxy from ``127.0.0.1:port`` (a free port) to ``upstream`` (host, port); see the
    module doc. ``start()``/``stop()``; ``swallow()``, ``reset()`` from any thread.
    ``connections``: client connections accepted so far; ``resets``: connections reset."""

    def __init__(self, upstream: tuple[str, int]):
        self.upstream = upstream
        self.host = "127.0.0.1"
        self._listener = socket.socket()
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.bind((self.host, 0))
        self._listener.listen(64)
        self._listener.setblocking(False)
        self.port = int(self._listener.getsockname()[1])
        self._sel = selectors.DefaultSelector()
        self._peer: dict[socket.socket, socket.socket | None] = {}
        self._clients: set[socket.socket] = set()
        self._orders: queue.Queue = queue.Queue()
        self._swallowing = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.connections = self.resets = 0

    def start(self) -> "NetCut":
        self._sel.register(self._listener, selectors.EVENT_READ)
        self._thread = threading.Thread(target=self._run, name="netcut", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)

    def swallow(self) -> None:
        """From now on drop every byte, both ways, on every connection, old and new."""
        self._orders.put("swallow")

    def reset(self) -> None:
        """Reset every connection (RST both ways), then pass bytes again."""
        done = threading.Event()
        self._orders.put(("reset", done))
        done.wait(10)

    # the proxy's thread ------------------------------------------------------------
    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                self._obey()
                for key, _ in self._sel.select(timeout=0.05):
                    if key.fileobj is self._listener:
                        self._accept()
                    else:
                        self._pass(key.fileobj)
        finally:
            for s in list(self._peer):
                self._close(s, rst=True)
            self._sel.close()
            self._listener.close()

    def _obey(self) -> None:
        while True:
            try:
                order = self._orders.get_nowait()
            except queue.Empty:
                return
            if order == "swallow":
                self._swallowing = True
            else:
                _, done = order
                self.resets += len(self._clients)
                for s in list(self._peer):
                    self._close(s, rst=True)
                self._swallowing = False
                done.set()

    def _accept(self) -> None:
        try:
            client, _ = self._listener.accept()
        except BlockingIOError:
            return
        self.connections += 1
        server = None
        if not self._swallowing:
            try:
                server = socket.create_connection(self.upstream, timeout=2)
            except OSError:
                _rst(client)                     # the server is down: the client learns at once
                return
            server.setblocking(True)
            self._peer[server] = client
            self._sel.register(server, selectors.EVENT_READ)
        client.setblocking(True)
        self._clients.add(client)
        self._peer[client] = server
        self._sel.register(client, selectors.EVENT_READ)

    def _pass(self, s: socket.socket) -> None:
        if s not in self._peer:
            return
        try:
            data = s.recv(65536)
        except OSError:
            data = b""
        if not data:                             # one side closed: close the pair as it did
            self._close(s, rst=False)
            return
        peer = self._peer[s]
        if self._swallowing or peer is None:
            return
        try:
            peer.sendall(data)
        except OSError:
            self._close(s, rst=True)

    def _close(self, s: socket.socket, rst: bool) -> None:
        peer = self._peer.pop(s, None)
        for sock in (s, peer):
            if sock is None:
                continue
            self._peer.pop(sock, None)
            self._clients.discard(sock)
            try:
                self._sel.unregister(sock)
            except (KeyError, ValueError):
                pass
            if rst:
                _rst(sock)
            else:
                sock.close()


def _rst(sock: socket.socket) -> None:
    """Close ``sock`` with an RST instead of a FIN."""
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    except OSError:
        pass
    sock.close()
