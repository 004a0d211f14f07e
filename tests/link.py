"""A network link between a robot and the broker that tests can break: a TCP proxy on 127.0.0.1.

    link = NetworkLink(broker_port).start()
    url = link.url(account.amqp_url)     # the robot connects through the link
    link.cut()                           # connections dropped, new ones refused: the robot is cut off
    link.restore()                       # it can connect again
    link.mute_replies()                  # the broker's answers (confirms) are lost on the way back
    link.hold_confirms(5)                # the broker's confirms arrive 5 s late, its other answers at once
    link.drop_connections()              # the open connections break; the link stays up
    link.stall_after(200_000)            # after 200 kB more from the robot, its side stops moving
    link.resume()                        # and moves again
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
        self._hold_confirms_s = 0.0
        self._partial: dict[socket.socket, bytearray] = {}
        self._held: list[tuple[float, socket.socket, bytes]] = []
        self._budget: int | None = None
        """Bytes the clients' side may still send before it stalls; None: no limit."""
        self._stalled: list[tuple[socket.socket, socket.socket]] = []
        """Confirm frames on their way back, with when each goes on (in order)."""
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

    def hold_confirms(self, seconds: float) -> None:
        """Hold each confirm (``basic.ack``, ``basic.nack``) the broker sends for ``seconds``, and
        pass its other frames at once: a broker that is alive, and slow to confirm."""
        self._hold_confirms_s = seconds

    def stall_after(self, n_bytes: int) -> None:
        """Pass ``n_bytes`` more from the clients' side, then stop reading from it: its connections
        stay open and stop moving, mid-stream (the broker's side still answers)."""
        with self._lock:
            self._budget = n_bytes

    def resume(self) -> None:
        """End a stall: what the clients' side sent meanwhile goes on."""
        with self._lock:
            self._budget = None
            stalled, self._stalled = self._stalled, []
            for client, server in stalled:
                with contextlib.suppress(KeyError, ValueError, OSError):
                    self._selector.register(client, selectors.EVENT_READ, (server, False))

    @property
    def held_confirms(self) -> int:
        """How many confirms the link holds back now (:meth:`hold_confirms`)."""
        return len(self._held)

    @property
    def stalled(self) -> bool:
        """Whether the clients' side has used up its bytes and stopped moving."""
        with self._lock:
            return bool(self._stalled)

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
            while self._held and self._held[0][0] <= time.monotonic():
                _, destination, frame = self._held.pop(0)
                self._send(destination, frame)

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
        if not is_reply:
            self._spend(source, destination, len(data))
        if is_reply and self._hold_confirms_s:
            self._pass_frames(source, destination, data)
            return
        if not self._send(destination, data):
            self._close_pair(source)

    def _spend(self, client: socket.socket, server: socket.socket, n_bytes: int) -> None:
        """Count what the client sent against the stall's budget; at its end, stop reading from it
        (what was read still goes on: the stall may come a little after the budget)."""
        with self._lock:
            if self._budget is None:
                return
            self._budget -= n_bytes
            if self._budget <= 0 and (client, server) in self._pairs:
                with contextlib.suppress(KeyError, ValueError):
                    self._selector.unregister(client)
                self._stalled.append((client, server))

    def _pass_frames(self, source: socket.socket, destination: socket.socket, data: bytes) -> None:
        """Each whole AMQP frame of the broker's on, a confirm only after the hold (type 1, a
        method, of class 60 with method 80 or 120: basic.ack, basic.nack)."""
        buffer = self._partial.setdefault(source, bytearray())
        buffer += data
        while len(buffer) >= 7:
            end = 7 + int.from_bytes(buffer[3:7], "big") + 1
            if len(buffer) < end:
                return
            frame, buffer[:] = bytes(buffer[:end]), buffer[end:]
            confirm = (
                frame[0] == 1
                and frame[7:9] == (60).to_bytes(2, "big")
                and frame[9:11]
                in (
                    (80).to_bytes(2, "big"),
                    (120).to_bytes(2, "big"),
                )
            )
            if confirm:
                self._held.append((time.monotonic() + self._hold_confirms_s, destination, frame))
            else:
                self._send(destination, frame)

    def _send(self, destination: socket.socket, data: bytes) -> bool:
        try:
            destination.setblocking(True)
            destination.sendall(data)
            destination.setblocking(False)
        except OSError:
            return False
        return True

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
