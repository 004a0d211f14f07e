"""``fleetbus stats``: how the workers fare (their counts, what they wait for), the dead letters by
reason, how fast the recording grows (MB and inserts per minute), as tables and a plot, and what
each bound on growth removed (pruned records, messages full queues dropped)."""

from __future__ import annotations

import json
from collections import Counter
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from fleetbus.cli.context import clock, console, endpoint, errors, fail
from fleetbus.cli.services import with_recording, with_services
from fleetbus.cli.times import TIME_FORMS, parse_duration, parse_time
from fleetbus.workers.recorder.growth import LONGEST_BUCKET, SHORTEST_BUCKET, Growth, growth

if TYPE_CHECKING:
    from fleetbus.api.services.dead_letters import Listing
    from fleetbus.api.services.standalone import Services
    from fleetbus.api.services.stats import BoundCount, WorkerStatus


def _view(item: Growth) -> dict[str, object]:
    return {
        "start": item.start.isoformat(),
        "end": item.end.isoformat(),
        "seconds": item.seconds,
        "database_bytes": item.database_bytes,
        "grown_bytes": item.grown_bytes,
        "inserted": item.inserted,
        "megabytes_per_minute": item.megabytes_per_minute,
        "inserts_per_minute": item.inserts_per_minute,
    }


def _ago(moment: datetime | None, now: datetime) -> str:
    return "" if moment is None else f"{(now - moment).total_seconds():.0f} s ago"


def _workers() -> None:
    """Each worker's latest status: what it handled and failed on, and what it is retrying now."""
    from fleetbus.api.services.errors import Unavailable

    async def read(services: Services) -> list[WorkerStatus] | str:
        try:
            return await services.stats.workers()
        except Unavailable as unavailable:  # the rest is still shown
            return unavailable.detail

    statuses = with_services(read)
    if isinstance(statuses, str):
        console.print(f"workers: {statuses}")
        return
    if not statuses:
        console.print("workers: none has reported yet (a worker writes its status every few seconds)")
        return
    now = datetime.now(timezone.utc)
    table = Table(title="workers")
    columns = ("worker", "seen", "stored", "dead-lettered", "internal errors", "bad requests", "retries")
    for column in (*columns, "waiting for"):
        table.add_column(column, justify="left" if column in ("worker", "seen", "waiting for") else "right")
    for status in statuses:
        count = status.counters.get
        waiting = (
            f"{status.waiting_for} since {_ago(status.waiting_since, now)}: {status.last_error}"
            if status.waiting_for
            else ""
        )
        table.add_row(
            status.name,
            _ago(status.updated_at, now),
            str(count("stored", 0)),
            str(count("rejected", 0)),
            str(count("internal_errors", 0) + count("rpc_internal_errors", 0)),
            str(count("rpc_bad_requests", 0)),
            str(count("store_retries", 0)),
            waiting,
        )
    console.print(table)


def _dead_letters() -> None:

    async def read(services: Services) -> Listing:
        return await services.dead_letters.listing(1000)

    listing = with_services(read, endpoint().amqp_url)
    reasons = Counter(letter.reason for letter in listing.letters)
    shown = ", ".join(f"{reason} {count}" for reason, count in reasons.most_common())
    if shown and len(listing.letters) < listing.in_queue:
        shown += f" among the oldest {len(listing.letters):,}"
    console.print(
        f"dead letters: {listing.in_queue:,}" + (f" ({shown}); `fleetbus dlq` lists them" if shown else "")
    )


def _beacon_discards() -> None:
    counts = with_services(lambda services: services.beacon_discards.counts())
    if counts:
        each = ", ".join(
            f"{c.exchange} {c.count:,} (the last at {clock(c.last_at)[:-4]}: {c.last_reason})" for c in counts
        )
        console.print(
            f"beacons the broker discarded: {each}; `GET /beacons/discards` lists them", soft_wrap=True
        )


def stats(
    since: Annotated[str, typer.Option(help=f"from this time: {TIME_FORMS}")] = "1h",
    every: Annotated[str, typer.Option(help="one row per this much time: 1m, 10m, 1h")] = "1m",
    plot: Annotated[Path | None, typer.Option(help="also write a PNG plot here")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="JSON lines instead of a table")] = False,
) -> None:
    """The workers' statuses and the dead letters by reason; database growth (MB per minute) and
    inserts per minute over time, from the recorder's samples; then what each bound removed since
    the store began: records pruned, messages full queues dropped (--json: growth and bound rows)."""
    bucket = parse_duration(every, "--every")
    if not SHORTEST_BUCKET <= bucket <= LONGEST_BUCKET:
        fail(f"--every {every!r}: write a duration from 1s to 1d, like 1m, 10m or 1h", code=2)
    start = parse_time(since, "--since")
    if not as_json:
        _workers()
        _dead_letters()
        _beacon_discards()
    rows = growth(with_recording(lambda recording: recording.samples(start)), bucket)
    removed = with_services(lambda services: services.stats.removed())
    if as_json:
        for row in rows:
            typer.echo(json.dumps(_view(row)))
        for count in removed:
            typer.echo(json.dumps(count.as_dict()))
    elif not rows:
        console.print(
            f"no samples since {since}: the recorder samples the database every minute while it runs "
            "(`fleetbus recorder run --sample-every SECONDS`)"
        )
    else:
        table = Table(title=f"recording growth since {since}, per {every}")
        for column in ("until (UTC)", "database MB", "MB per minute", "inserts per minute", "inserted"):
            table.add_column(column, justify="left" if column.startswith("until") else "right")
        for row in rows:
            table.add_row(
                clock(row.end)[:-4],
                f"{row.database_bytes / 1e6:.2f}",
                f"{row.megabytes_per_minute:.3f}",
                f"{row.inserts_per_minute:.0f}",
                str(row.inserted),
            )
        seconds = sum(row.seconds for row in rows)
        inserted = sum(row.inserted for row in rows)
        grown = sum(row.grown_bytes for row in rows)
        console.print(table)
        console.print(
            f"over {seconds / 60:.1f} min: {grown / 1e6 / seconds * 60:.3f} MB per minute, "
            f"{inserted / seconds * 60:.0f} inserts per minute"
        )
    if not as_json:
        console.print(_bounds_table(removed))
    if plot is not None:
        say = errors if as_json else console
        if rows:
            from fleetbus.cli.plots import plot_growth  # matplotlib loads in a second: only when asked

            plot_growth(
                [row.end for row in rows],
                [row.megabytes_per_minute for row in rows],
                [row.inserts_per_minute for row in rows],
                plot,
            )
            say.print(f"wrote {plot}")
        else:
            say.print("nothing to plot")


def _bounds_table(removed: list[BoundCount]) -> Table | str:
    """Per bound and subject: what it removed, since when (see README, "Bounds")."""
    if not removed:
        return "no bound has removed anything yet"
    table = Table(title="removed by the bounds on growth (README: Bounds)")
    for column in ("bound", "what", "removed", "first (UTC)", "last (UTC)"):
        table.add_column(column, justify="right" if column == "removed" else "left")
    for count in removed:
        table.add_row(
            count.bound,
            count.subject,
            f"{count.count:,}",
            clock(count.first_at)[:-4],
            clock(count.last_at)[:-4],
        )
    return table
