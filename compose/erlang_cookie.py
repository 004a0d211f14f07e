"""The Erlang cookie central's RabbitMQ nodes share, made once, in each node's own data folder.

Run by compose.yaml's one-shot ``certs`` service (as root), before any node starts:

    python compose/erlang_cookie.py /cookie/rabbitmq /cookie/rabbitmq-2 /cookie/rabbitmq-3

Each argument is a node's data folder (its ``/var/lib/rabbitmq``, which is the node's home): the
cookie is written there as ``.erlang.cookie``, owned by RabbitMQ's user (uid 999), readable by it
alone (0400), where RabbitMQ and its command-line tools read it. A cookie already in one folder
(a node that ran before) is kept and given to the others; else a random one is made. The cookie
never appears in a command line or in compose.yaml, and there is no default.
"""

from __future__ import annotations

import os
import secrets
import sys
from pathlib import Path

RABBITMQ_UID = 999
COOKIE = ".erlang.cookie"


def share_cookie(homes: list[Path], uid: int = RABBITMQ_UID) -> str:
    """The nodes' cookie, written where it is missing or differs; returns nothing secret to print."""
    files = [home / COOKIE for home in homes]
    kept = [path.read_text().strip() for path in files if path.exists()]
    cookie = kept[0] if kept and kept[0] else secrets.token_hex(32).upper()
    for path in files:
        if path.exists() and path.read_text().strip() == cookie:
            continue
        path.unlink(missing_ok=True)
        path.parent.mkdir(parents=True, exist_ok=True)
        descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o400)
        with os.fdopen(descriptor, "w") as handle:
            handle.write(cookie)
        os.chown(path, uid, uid)
    return f"the Erlang cookie is in {len(files)} node folders ({'kept' if kept else 'made'})"


if __name__ == "__main__":
    print(share_cookie([Path(arg) for arg in sys.argv[1:]]))
