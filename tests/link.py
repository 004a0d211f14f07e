"""A network link between a robot and the broker that tests can break: a TCP proxy on 127.0.0.1.

    link = NetworkLink(broker_port).start()
    url = link.url(account.amqp_url)     # the robot connects through the link
    link.cut()                           # connections dropped, new ones refused: the robot is cut off
    link.restore()                       # it can connect again
    link.mute_replies()                  # the broker's answers (confirms) are lost on the way back
    link.drop_connections()              # the open connections break; the link stays up
    link.attempts                        # when each connection attempt reached the link

It breaks the robot's connection the way a field network does, while the broker, the workers
and every other robot carry on.
"""

from __future__ import annotations

import contextlib
import selectors
import socket
import threading
import time
from urllib.parse import urlsplit, urlunsplit


class NetworkLink:
    def __init__(self, target_port: int, target_host: str = "127.0.0.1") -> None:
        self._target = (target_host, target_port)
        self._listener: socket.socket | None = None
        self.port = 0
        self._lock = threading.Lock()
        self._pairs: list[tuple[socket.socket, socket.socket]] = []
        self._muted = False
        self._stopped = threading.Event()
        self._selector = selectors.DefaultSelector()
        self._thread = threading.Thread(target=self._pump, name="network-link", daemon=True)
        self.connections = 0
        self.attempts: list[float] = []
        """``time.monotonic()`` of each connection the link accepted, also those it could not
        forward (the broker is down)."""

    def start(self) -> NetworkLink:
        self._listen()
        self._thread.start()
        return self

    def url(self, amqp_url: str) -> str:
        """``amqp_url`` going through this link."""
        parts = urlsplit(amqp_url)
        credentials = parts.netloc.rpartition("@")[0]
        return urlunsplit((parts.scheme, f"{credentials}@127.0.0.1:{self.port}", parts.path, parts.query, ""))

    def _listen(self) -> None:
        listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(("127.0.0.1", self.port))
        listener.listen(64)
        listener.setblocking(False)
        self.port = listener.getsockname()[1]
        with self._lock:
            self._listener = listener
            self._selector.register(listener, selectors.EVENT_READ, None)

    def cut(self) -> None:
        """Drop every connection and refuse new ones, as if the robot lost the network."""
        with self._lock:
            if self._listener is not None:
                self._selector.unregister(self._listener)
                self._listener.close()
                self._listener = None
        self.drop_connections()

    def restore(self) -> None:
        self._muted = False
        with self._lock:
            listening = self._listener is not None
        if not listening:
            self._listen()

    def mute_replies(self) -> None:
        """Keep forwarding what the robot sends; lose everything the broker answers."""
        self._muted = True

    def drop_connections(self) -> None:
        with self._lock:
            pairs, self._pairs = self._pairs, []
            for client, server in pairs:
                for sock in (client, server):
                    with contextlib.suppress(KeyError, ValueError):
                        self._selector.unregister(sock)
                    with contextlib.suppress(OSError):
                        sock.shutdown(socket.SHUT_RDWR)
                    sock.close()

    def stop(self) -> None:
        self.cut()
        self._stopped.set()
        self._thread.join(5)

    def _pump(self) -> None:
        while not self._stopped.is_set():
            try:
                ready = self._selector.select(timeout=0.05)
            except (OSError, ValueError):  # a socket closed by cut() under the selector
                continue
            for key, _ in ready:
                if key.data is None:
                    self._accept(key.fileobj)  # type: ignore[arg-type]
                else:
                    self._forward(key.fileobj, *key.data)  # type: ignore[arg-type]

    def _accept(self, listener: socket.socket) -> None:
        try:
            client, _ = listener.accept()
        except OSError:
            return
        self.attempts.append(time.monotonic())
        try:
            server = socket.create_connection(self._target, timeout=5)
        except OSError:
            client.close()
            return
        client.setblocking(False)
        server.setblocking(False)
        with self._lock:
            self._pairs.append((client, server))
            self._selector.register(client, selectors.EVENT_READ, (server, False))
            self._selector.register(server, selectors.EVENT_READ, (client, True))
        self.connections += 1

    def _forward(self, source: socket.socket, destination: socket.socket, is_reply: bool) -> None:
        try:
            data = source.recv(65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if not data:
            self._close_pair(source)
            return
        if is_reply and self._muted:
            return
        try:
            destination.setblocking(True)
            destination.sendall(data)
            destination.setblocking(False)
        except OSError:
            self._close_pair(source)

    def _close_pair(self, sock: socket.socket) -> None:
        with self._lock:
            for pair in self._pairs:
                if sock in pair:
                    self._pairs.remove(pair)
                    for end in pair:
                        with contextlib.suppress(KeyError, ValueError):
                            self._selector.unregister(end)
                        end.close()
                    return
