"""Run mongoeco's MongoDB wire-protocol server on 127.0.0.1 (Python 3.13); print its port.

    .venv-mongoeco/bin/python tests/store/mongoeco_server.py [PORT] [--path FILE]

Used by the store contract tests when FLEETBUS_MONGODB_URL is not set: real pymongo clients
talk to it over a socket. In memory by default; with ``--path`` its data lives in that file
(mongoeco's SQLite engine), so a test can kill the server and start it again on the same data.
It runs until it is terminated.
"""

import argparse
import asyncio

from mongoeco.wire import AsyncMongoEcoProxyServer


async def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("port", type=int, nargs="?", default=0)
    parser.add_argument("--path")
    args = parser.parse_args()
    engine = None
    if args.path:
        from mongoeco.engines.sqlite import SQLiteEngine

        engine = SQLiteEngine(args.path)
    async with AsyncMongoEcoProxyServer(host="127.0.0.1", port=args.port, engine=engine) as server:
        print(server.address.port, flush=True)
        await asyncio.Event().wait()


if __name__ == "__main__":
    asyncio.run(main())
