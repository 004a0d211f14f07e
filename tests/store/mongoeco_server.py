"""Run mongoeco's MongoDB wire-protocol server on 127.0.0.1 (Python 3.13); print its port.

    .venv-mongoeco/bin/python tests/store/mongoeco_server.py [PORT]

Used by the store contract tests when FLEETBUS_MONGODB_URL is not set: real pymongo clients
talk to it over a socket. It runs until it is terminated.
"""

import asyncio
import sys

from mongoeco.wire import AsyncMongoEcoProxyServer


async def main() -> None:
    port = int(sys.argv[1]) if len(sys.argv) > 1 else 0
    async with AsyncMongoEcoProxyServer(host="127.0.0.1", port=port) as server:
        print(server.address.port, flush=True)
        await asyncio.Event().wait()


if __name__ == "__main__":
    asyncio.run(main())
