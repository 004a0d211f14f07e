"""``fleetbus tail PATTERN``: follow your stream, each message with its origin.

fleetbus tail                         # everything, live, as the user of FLEETBUS_USER_URL
fleetbus tail 'explorer1.*' --user ops1 --since 10m   # history first, then live
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import sys
from datetime import timezone
from typing import Annotated

import aiormq.exceptions
import typer
from rich.markup import escape

from fleetbus.broker.tail import Seen, StreamClosed, follow
from fleetbus.cli.context import console, fail, no_password_in_argv, settings
from fleetbus.cli.times import TIME_FORMS, parse_time

#: Seconds Ctrl-C waits for the broker to close the follow before the command ends anyway.
STOP_S = 3.0


def user_url(user: str | None, url: str | None) -> str:
    no_password_in_argv(
        url, "--url", "in FLEETBUS_USER_URL, or keep it with `fleetbus api login NAME` and use --user"
    )
    url = url or settings().user_url
    if url:
        return url
    if user:
        saved = settings().accounts_dir / f"{user}.url"
        if saved.exists():
            return saved.read_text().strip()
        fail(f"no credentials for {user!r}: `fleetbus api login {user}` keeps them, or pass --url")
    fail("who is following? use --user NAME (after `fleetbus api login NAME`), --url or FLEETBUS_USER_URL")


def line(seen: Seen) -> str:
    clock = seen.timestamp.astimezone(timezone.utc).strftime("%H:%M:%S") if seen.timestamp else "--:--:--"
    origin = f"[bold]{escape(seen.user_id or '?')}[/] via {escape(seen.exchange or '(default)')}"
    return f"{clock} {origin} [cyan]{escape(seen.routing_key)}[/] {escape(seen.summary())}"


def tail(
    pattern: Annotated[str, typer.Argument(help="routing keys to show: '*' one word, '#' any")] = "#",
    user: Annotated[
        str | None, typer.Option(help="follow as this user (credentials kept by `api login`)")
    ] = None,
    url: Annotated[str | None, typer.Option(help="your broker URL (default: FLEETBUS_USER_URL)")] = None,
    since: Annotated[str | None, typer.Option(help=f"replay from this time first: {TIME_FORMS}")] = None,
    count: Annotated[int | None, typer.Option(help="stop after this many messages")] = None,
    idle: Annotated[float | None, typer.Option(help="stop after this many seconds without one")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="one JSON object per line")] = False,
) -> None:
    """Follow live messages from your stream (<user>.stream): the beacons, and the robots you mounted."""
    amqp_url = user_url(user, url)
    start = parse_time(since, "--since")

    def show(seen: Seen) -> None:
        if as_json:
            print(json.dumps(seen.as_dict()), flush=True)
        else:
            console.print(line(seen), soft_wrap=True, highlight=False)

    if not as_json:
        console.print(
            f"following {pattern!r}" + (f" since {start.isoformat()}" if start else "") + " (Ctrl-C stops)"
        )

    async def following() -> None:
        task = asyncio.ensure_future(
            follow(amqp_url, pattern, since=start, on_message=show, count=count, idle_timeout=idle)
        )
        loop = asyncio.get_running_loop()

        def stop() -> None:
            # Ctrl-C ends the follow at once: the stream consumer and the connection are closed,
            # and if the broker does not answer their close within STOP_S (a loaded broker, a link
            # gone) the command still ends: nothing of a follower waits to be written
            task.cancel()
            loop.call_later(STOP_S, gone)

        def gone() -> None:
            sys.stdout.flush()
            os._exit(130)  # as a shell reports Ctrl-C

        loop.add_signal_handler(signal.SIGINT, stop)
        with contextlib.suppress(asyncio.CancelledError):
            await task

    try:
        asyncio.run(following())
    except KeyboardInterrupt:
        pass
    except StreamClosed as error:
        fail(str(error))
    except aiormq.exceptions.ChannelNotFoundEntity as error:
        fail(f"no stream to follow: {error} (only operators and supervisors have one)")
    except (aiormq.exceptions.AMQPError, ConnectionError) as error:
        fail(f"the broker refused or failed: {error!r}")
