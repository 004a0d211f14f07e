"""Each calling thread's own connection to the broker, for service calls and notifications.

A pika ``BlockingConnection`` belongs to the thread that uses it: only
``add_callback_threadsafe`` may be called from another. Robot code often listens for
notifications on one thread while another calls the services (the guide's listener), so each
thread that calls the client gets a connection of its own, with its service channel and the
connection its warden's resync of open hazards was made on.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

import pika
import pika.exceptions

from fleetbus.publishers.closing import close_quietly
from fleetbus.publishers.errors import ClientClosed
from fleetbus.publishers.rpc import RpcChannel


@dataclass
class ThreadSession:
    """What one thread uses of the broker through the client."""

    thread: threading.Thread
    connection: pika.BlockingConnection | None = None
    rpc: RpcChannel | None = None
    resynced_on: pika.BlockingConnection | None = None
    """The connection on which this thread last rebuilt its list of open hazards."""


class Sessions:
    """The calling threads' connections, opened with ``connect`` when a thread first needs one."""

    def __init__(self, connect: Callable[[], pika.BlockingConnection], robot_id: str) -> None:
        self._connect = connect
        self._robot_id = robot_id
        self._local = threading.local()
        self._lock = threading.Lock()
        self._sessions: list[ThreadSession] = []
        self._closed = False

    @property
    def closed(self) -> bool:
        return self._closed

    def mine(self) -> ThreadSession:
        """The calling thread's session."""
        session: ThreadSession | None = getattr(self._local, "session", None)
        if session is None:
            session = self._local.session = ThreadSession(threading.current_thread())
            with self._lock:
                ended = [each for each in self._sessions if not each.thread.is_alive()]
                self._sessions = [each for each in self._sessions if each.thread.is_alive()]
                self._sessions.append(session)
            for each in ended:  # their thread is gone: nobody else uses these connections
                if each.connection is not None:
                    close_quietly(each.connection)
        return session

    def connection(self) -> pika.BlockingConnection:
        """The calling thread's open connection: opened now if it has none or it broke.

        Raises :class:`ClientClosed` once the client was closed."""
        session = self.mine()
        if session.connection is not None and session.connection.is_open and not self._closed:
            return session.connection
        session.rpc = None
        if self._closed:
            self.forget()
            raise ClientClosed("the robot client is closed")
        connection = self._connect()
        with self._lock:
            if not self._closed:
                session.connection = connection
                return connection
        close_quietly(connection)
        raise ClientClosed("the robot client is closed")

    def rpc(self) -> RpcChannel:
        """The calling thread's service channel, on its connection."""
        session = self.mine()
        connection = self.connection()  # a new one, without a service channel, if it broke
        if session.rpc is None or not session.rpc.is_open:  # the broker may close just the channel
            session.rpc = RpcChannel(connection, self._robot_id)
        return session.rpc

    def forget(self) -> None:
        """Close and drop the calling thread's connection (it broke, or the client was closed)."""
        session = self.mine()
        connection, session.connection, session.rpc = session.connection, None, None
        if connection is not None:
            close_quietly(connection)

    def close(self) -> None:
        """Close every thread's connection: the caller's and those of threads that ended at once,
        the others' in their own thread (the next time pika runs there: a listener within
        :data:`fleetbus.publishers.client.STOP_CHECK_S`, or when the thread calls the client again)."""
        with self._lock:
            self._closed = True
            sessions, self._sessions = self._sessions, []
        me = threading.current_thread()
        for session in sessions:
            connection = session.connection
            if connection is None or not connection.is_open:
                continue
            if session.thread is me or not session.thread.is_alive():
                close_quietly(connection)
                continue
            try:
                connection.add_callback_threadsafe(lambda c=connection: close_quietly(c))
            except pika.exceptions.AMQPError:
                pass  # closed meanwhile
