"""A small client of RabbitMQ's management HTTP API: the parts fleetbus administers with.

Accounts, permissions, topic permissions and virtual hosts have no AMQP operations, so the
service manages them here; queues, exchanges and bindings are declared over AMQP by
:mod:`fleetbus.broker.topology`.
"""

from __future__ import annotations

import functools
import re
import ssl
from collections import Counter
from collections.abc import Collection
from datetime import datetime, timezone
from typing import Any
from urllib.parse import quote, urlsplit

import httpx

from fleetbus.broker.urls import masked_in_text
from fleetbus.publishers.addresses import split_addresses

#: Requests the management API handles the same when sent twice.
IDEMPOTENT = frozenset({"GET", "HEAD", "PUT", "DELETE"})
#: What fleetbus reads of a connection: whose it is and since when. The management API sends only
#: these (a connection's whole entry is over a kilobyte of statistics: 370 KB a listing for 300
#: robots' connections, 16 KB with these two, a third of the broker's time to answer).
CONNECTION_COLUMNS = {"columns": "user,connected_at", "disable_stats": "true"}
#: Queues a page of a filtered listing holds (the management API's largest page).
QUEUES_PAGE = 500


class ManagementError(RuntimeError):
    """The management API refused or failed a request; the message quotes its answer (with any
    URL's password masked: a refused shovel's answer quotes its URIs)."""


@functools.cache
def tls_context(cafile: str | None = None) -> ssl.SSLContext:
    """httpx's default TLS settings (the system's CAs), and ``cafile``'s CA too, made once per
    process: httpx loads the certificates (about 25 ms of CPU) for every client it makes, even one
    that only talks plain http://."""
    context = httpx.create_ssl_context()
    if cafile:
        context.load_verify_locations(cafile=cafile)
    return context


def verification(base_url: str) -> ssl.SSLContext:
    """How an https:// management API is verified: its certificate and host name, against the
    system's CAs and fleetbus's CA (``FLEETBUS_TLS_CA``, else the one ``fleetbus certs make`` made)."""
    if not base_url.startswith("https:"):
        return tls_context()
    from fleetbus.settings import load_settings

    ca = load_settings().ca_file
    return tls_context(str(ca) if ca.exists() else None)


def _q(part: str) -> str:
    return quote(part, safe="")


class ManagementAPI:
    """The management API of one broker, or of a cluster: ``base_url`` may list several nodes
    (``http://h1:15672,h2:15672/``, as :mod:`fleetbus.publishers.addresses` writes broker URLs). A
    request that cannot reach the node in use (refused, timed out) goes to the next one, and the
    client stays there; an answer, even a refusal, is the cluster's answer."""

    def __init__(self, base_url: str, username: str, password: str, timeout: float = 15.0) -> None:
        self._clients = [
            httpx.Client(
                base_url=url.rstrip("/") + "/api/",
                auth=(username, password),
                timeout=timeout,
                verify=verification(url),
            )
            for url in split_addresses(base_url)
        ]
        self._current = 0

    @property
    def base_url(self) -> str:
        """The node in use, ``http://host:port/``."""
        return str(self._clients[self._current].base_url).removesuffix("api/")

    def _send(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        failed: httpx.TransportError | None = None
        for step in range(len(self._clients)):
            index = (self._current + step) % len(self._clients)
            try:
                response = self._request_once_more(self._clients[index], method, path, **kwargs)
            except httpx.TransportError as error:
                failed = error
                continue
            self._current = index
            return response
        assert failed is not None
        raise failed

    @staticmethod
    def _request_once_more(client: httpx.Client, method: str, path: str, **kwargs: Any) -> httpx.Response:
        """The request, sent again once when the node closed a kept-alive connection just as it was
        reused (no answer at all: the request was not handled). Only for methods that may be
        repeated; the management API closes connections idle for a while, and a long-lived client
        (the API's, a site's) reuses one now and then as it closes."""
        try:
            return client.request(method, path, **kwargs)
        except httpx.RemoteProtocolError:
            if method.upper() not in IDEMPOTENT:
                raise
            return client.request(method, path, **kwargs)

    @classmethod
    def from_urls(cls, management_url: str, amqp_url: str, timeout: float = 15.0) -> ManagementAPI:
        """Use the credentials of an AMQP URL (the administrator's) against the HTTP API."""
        parts = urlsplit(amqp_url)
        return cls(management_url, parts.username or "", parts.password or "", timeout)

    def close(self) -> None:
        for client in self._clients:
            client.close()

    def __enter__(self) -> ManagementAPI:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _request(self, method: str, path: str, **kwargs: Any) -> Any:
        response = self._send(method, path, **kwargs)
        if response.status_code == 404 and method == "DELETE":
            return None
        if response.status_code >= 400:
            answer = masked_in_text(response.text.strip())
            raise ManagementError(f"{method} /api/{path} -> {response.status_code}: {answer}")
        return response.json() if response.content else None

    # accounts
    def put_user(self, name: str, password: str, tags: str = "") -> None:
        self._request("PUT", f"users/{_q(name)}", json={"password": password, "tags": tags})

    def put_user_hash(self, name: str, password_hash: str, hashing_algorithm: str, tags: str = "") -> None:
        """Create or replace an account with a password hash another broker made (the same
        password then works on both)."""
        body = {"password_hash": password_hash, "hashing_algorithm": hashing_algorithm, "tags": tags}
        self._request("PUT", f"users/{_q(name)}", json=body)

    def put_user_without_password(self, name: str, tags: str = "") -> None:
        """Create or replace an account no password logs in as (an empty ``password_hash``): it
        logs in by other means only, a client certificate (EXTERNAL)."""
        self._request("PUT", f"users/{_q(name)}", json={"password_hash": "", "tags": tags})

    def get_user(self, name: str) -> dict[str, Any] | None:
        response = self._send("GET", f"users/{_q(name)}")
        return response.json() if response.status_code == 200 else None

    def put_user_tags(self, name: str, tags: str) -> None:
        """Change an account's tags and keep its password (the API wants the hash sent back)."""
        user = self._request("GET", f"users/{_q(name)}")
        body = {"tags": tags, "password_hash": user.get("password_hash", "")}
        if user.get("hashing_algorithm"):
            body["hashing_algorithm"] = user["hashing_algorithm"]
        self._request("PUT", f"users/{_q(name)}", json=body)

    def delete_user(self, name: str) -> None:
        self._request("DELETE", f"users/{_q(name)}")

    def list_users(self) -> list[dict[str, Any]]:
        return self._request("GET", "users")

    # permissions
    def topic_permissions(self, user: str) -> list[dict[str, Any]]:
        """``user``'s topic permissions, in every virtual host."""
        return list(self._request("GET", f"users/{_q(user)}/topic-permissions") or [])

    def import_definitions(self, definitions: dict[str, Any], timeout: float = 600.0) -> None:
        """RabbitMQ's definitions import: users, permissions, exchanges, queues and bindings of a
        document at once (each item names its virtual host); what exists is updated. ``timeout``
        is the import's own, not the client's: on a three-node cluster 500 robots' quorum queues
        took over 15 s, and a client that gave up would send the same import to the next node."""
        self._request("POST", "definitions", json=definitions, timeout=timeout)

    def put_permissions(self, vhost: str, user: str, configure: str, write: str, read: str) -> None:
        body = {"configure": configure, "write": write, "read": read}
        self._request("PUT", f"permissions/{_q(vhost)}/{_q(user)}", json=body)

    def get_permissions(self, vhost: str, user: str) -> dict[str, Any] | None:
        response = self._send("GET", f"permissions/{_q(vhost)}/{_q(user)}")
        return response.json() if response.status_code == 200 else None

    def delete_permissions(self, vhost: str, user: str) -> None:
        self._request("DELETE", f"permissions/{_q(vhost)}/{_q(user)}")

    def list_permissions(self, vhost: str) -> list[dict[str, Any]]:
        """Every account's permissions in ``vhost``: ``user``, ``configure``, ``write``, ``read``."""
        return self._request("GET", f"vhosts/{_q(vhost)}/permissions")

    def list_topic_permissions(self, vhost: str) -> list[dict[str, Any]]:
        """Every topic permission in ``vhost``: ``user``, ``exchange``, ``write``, ``read``."""
        return self._request("GET", f"vhosts/{_q(vhost)}/topic-permissions")

    def put_topic_permissions(self, vhost: str, user: str, exchange: str, write: str, read: str) -> None:
        body = {"exchange": exchange, "write": write, "read": read}
        self._request("PUT", f"topic-permissions/{_q(vhost)}/{_q(user)}", json=body)

    # policies
    def put_policy(
        self,
        vhost: str,
        name: str,
        pattern: str,
        definition: dict[str, Any],
        priority: int = 0,
        apply_to: str = "queues",
    ) -> None:
        """A policy on the queues whose names match ``pattern`` (idempotent: replaces one of that
        name); ``apply_to``: ``queues``, or on RabbitMQ 4 one type of them (``quorum_queues``...)."""
        body = {"pattern": pattern, "definition": definition, "apply-to": apply_to, "priority": priority}
        self._request("PUT", f"policies/{_q(vhost)}/{_q(name)}", json=body)

    # shovels (the rabbitmq_shovel plugin's runtime parameters; their status needs
    # rabbitmq_shovel_management)
    def put_shovel(self, vhost: str, name: str, definition: dict[str, Any]) -> None:
        """Create or replace the dynamic shovel ``name``, started with ``definition``. One that
        exists is deleted first: RabbitMQ 3.10 replacing a running shovel's definition in place
        can keep the old one running, its new definition stored but not started, for as long as
        the old one's connections stay open.

        A running shovel that already has ``definition`` is left as it is: RabbitMQ restarts a
        shovel whose definition is put again, even unchanged, and a restart puts back what it had
        taken and not yet acked (sent again; at a full queue that drops its oldest, dropped and
        counted although its copy got through)."""
        current = self.get_shovel(vhost, name)
        if current == definition and self._shovel_running(vhost, name):
            return
        if current is not None:
            self.delete_shovel(vhost, name)
        self._request("PUT", f"parameters/shovel/{_q(vhost)}/{_q(name)}", json={"value": definition})

    def _shovel_running(self, vhost: str, name: str) -> bool:
        return any(s.get("name") == name and s.get("state") == "running" for s in self.shovel_status(vhost))

    def get_shovel(self, vhost: str, name: str) -> dict[str, Any] | None:
        response = self._send("GET", f"parameters/shovel/{_q(vhost)}/{_q(name)}")
        return response.json().get("value") if response.status_code == 200 else None

    def delete_shovel(self, vhost: str, name: str) -> None:
        self._request("DELETE", f"parameters/shovel/{_q(vhost)}/{_q(name)}")

    def shovel_status(self, vhost: str) -> list[dict[str, Any]]:
        """Each shovel of ``vhost`` as it runs now: ``name``, ``state`` (running, starting,
        terminated), ``timestamp`` of the state, ``reason`` when terminated."""
        return self._request("GET", f"shovels/{_q(vhost)}")

    # virtual hosts
    def put_vhost(self, vhost: str) -> None:
        self._request("PUT", f"vhosts/{_q(vhost)}")

    def set_tracing(self, vhost: str, on: bool) -> None:
        """Turn RabbitMQ's firehose (``amq.rabbitmq.trace``) on or off for a virtual host."""
        self._request("PUT", f"vhosts/{_q(vhost)}", json={"tracing": on})

    def get_vhost(self, vhost: str) -> dict[str, Any]:
        return self._request("GET", f"vhosts/{_q(vhost)}")

    def delete_vhost(self, vhost: str, timeout: float = 180.0) -> None:
        """The broker answers once every queue of it is deleted: minutes for thousands of queues,
        so this waits longer than the other calls."""
        self._request("DELETE", f"vhosts/{_q(vhost)}", timeout=timeout)

    def vhost_rate_samples(self, vhost: str, age_s: int, every_s: int) -> dict[str, Any]:
        """The virtual host with its ``message_stats`` sampled: each ``*_details`` carries
        ``samples`` (the cumulative count, newest first) every ``every_s`` over the last ``age_s``
        seconds, as far as the broker's retention policy keeps them (an hour at one a minute, by
        default)."""
        params = {"msg_rates_age": age_s, "msg_rates_incr": every_s}
        return self._request("GET", f"vhosts/{_q(vhost)}", params=params)

    # bindings (mount and unmount change them while the service runs)
    def bind(
        self,
        vhost: str,
        source: str,
        destination: str,
        routing_key: str,
        *,
        to_exchange: bool = False,
        arguments: dict[str, Any] | None = None,
    ) -> None:
        kind = "e" if to_exchange else "q"
        body = {"routing_key": routing_key, "arguments": arguments or {}}
        self._request("POST", f"bindings/{_q(vhost)}/e/{_q(source)}/{kind}/{_q(destination)}", json=body)

    def unbind(
        self, vhost: str, source: str, destination: str, routing_key: str, *, to_exchange: bool = False
    ) -> None:
        """Remove every binding between the two with this routing key (whatever its arguments)."""
        self.unbind_keys(vhost, source, destination, (routing_key,), to_exchange=to_exchange)

    def unbind_keys(
        self,
        vhost: str,
        source: str,
        destination: str,
        routing_keys: Collection[str],
        *,
        to_exchange: bool = False,
    ) -> None:
        """Remove every binding between the two with one of these routing keys; absent ones are fine."""
        kind = "e" if to_exchange else "q"
        path = f"bindings/{_q(vhost)}/e/{_q(source)}/{kind}/{_q(destination)}"
        response = self._send("GET", path)
        if response.status_code == 404:  # either end is gone, and the binding with it
            return
        if response.status_code >= 400:
            raise ManagementError(f"GET /api/{path} -> {response.status_code}: {response.text.strip()}")
        for binding in response.json():
            if binding["routing_key"] in routing_keys:
                self._request("DELETE", f"{path}/{_q(binding['properties_key'])}")

    # observation
    def list_bindings(self, vhost: str) -> list[dict[str, Any]]:
        return self._request("GET", f"bindings/{_q(vhost)}")

    def exchange_bindings(self, vhost: str, exchange: str, side: str = "source") -> list[dict[str, Any]]:
        """The bindings whose ``side`` (source or destination) is ``exchange``; none if it does not exist."""
        response = self._send("GET", f"exchanges/{_q(vhost)}/{_q(exchange)}/bindings/{side}")
        if response.status_code == 404:
            return []
        if response.status_code >= 400:
            raise ManagementError(
                f"GET bindings of {exchange} -> {response.status_code}: {response.text.strip()}"
            )
        return response.json()

    def list_queues(self, vhost: str) -> list[dict[str, Any]]:
        return self._request("GET", f"queues/{_q(vhost)}")

    def list_queues_named(
        self, vhost: str, prefix: str, columns: Collection[str], page_size: int = QUEUES_PAGE
    ) -> list[dict[str, Any]]:
        """The queues of ``vhost`` whose names begin with ``prefix``, each with ``columns`` only:
        chosen by the broker, a page at a time, so that a fleet's own queues (two a robot: 2,000
        entries, 1.7 MB, for 1,000 robots) are never sent."""
        found: list[dict[str, Any]] = []
        page = 1
        while True:
            params = {
                "page": page,
                "page_size": page_size,
                "name": f"^{re.escape(prefix)}",
                "use_regex": "true",
                "columns": ",".join(columns),
            }
            answer = self._request("GET", f"queues/{_q(vhost)}", params=params)
            found += answer["items"]
            if page >= answer["page_count"]:
                return found
            page += 1

    def get_queue(self, vhost: str, name: str) -> dict[str, Any]:
        return self._request("GET", f"queues/{_q(vhost)}/{_q(name)}")

    def list_exchanges(self, vhost: str) -> list[dict[str, Any]]:
        return self._request("GET", f"exchanges/{_q(vhost)}")

    def get_exchange(self, vhost: str, name: str) -> dict[str, Any] | None:
        response = self._send("GET", f"exchanges/{_q(vhost)}/{_q(name)}")
        return response.json() if response.status_code == 200 else None

    def list_consumers(self, vhost: str) -> list[dict[str, Any]]:
        return self._request("GET", f"consumers/{_q(vhost)}")

    def list_connections(self) -> list[dict[str, Any]]:
        return self._request("GET", "connections")

    def delete_queue(self, vhost: str, name: str) -> None:
        """Delete the queue (and its bindings); nothing when there is none."""
        self._request("DELETE", f"queues/{_q(vhost)}/{_q(name)}")

    def delete_exchange(self, vhost: str, name: str) -> None:
        """Delete the exchange (and the bindings from it); nothing when there is none."""
        self._request("DELETE", f"exchanges/{_q(vhost)}/{_q(name)}")

    def close_connections_of(self, user: str, reason: str) -> int:
        """Close every connection ``user`` has open on the broker (the broker tells each client
        ``reason``); how many. A connection that closed meanwhile is not counted."""
        listed = self._request("GET", "connections", params={"columns": "name,user", "disable_stats": "true"})
        closed = 0
        for connection in listed:
            if connection.get("user") == user:
                answer = self._send(
                    "DELETE", f"connections/{_q(connection['name'])}", headers={"X-Reason": reason}
                )
                closed += answer.status_code < 300
        return closed

    def list_vhost_connections(self, vhost: str) -> list[dict[str, Any]]:
        """The connections open on ``vhost``, each with its ``user`` and ``connected_at`` only."""
        return self._request("GET", f"vhosts/{_q(vhost)}/connections", params=CONNECTION_COLUMNS)

    def list_nodes(self) -> list[dict[str, Any]]:
        """The cluster's nodes: running, memory and disk alarms, file descriptors."""
        return self._request("GET", "nodes")

    def overview(self) -> dict[str, Any]:
        return self._request("GET", "overview")


def oldest_by_user(connections: list[dict[str, Any]]) -> dict[str, datetime]:
    """When each user's oldest open connection of ``connections`` was opened."""
    oldest: dict[str, datetime] = {}
    for connection in connections:
        user, at = connection.get("user"), connection.get("connected_at")
        if user and at:
            moment = datetime.fromtimestamp(at / 1000, timezone.utc)
            oldest[user] = min(oldest.get(user, moment), moment)
    return oldest


def users_of(connections: list[dict[str, Any]]) -> Counter[str]:
    """How many of ``connections`` (as the management API lists them) each user has open."""
    return Counter(str(connection.get("user", "?")) for connection in connections)


def connections_by_user(management: ManagementAPI, vhost: str) -> Counter[str]:
    """How many connections each user has open on ``vhost``: one call, however many users."""
    return users_of(management.list_vhost_connections(vhost))
