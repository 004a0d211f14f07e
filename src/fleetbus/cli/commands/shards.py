"""``fleetbus shards [rebalance]``: the ingest shards, their robots and workers; moving robots."""

from __future__ import annotations

import asyncio
import json
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.table import Table

from fleetbus.broker.accounts import vhost_of
from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.shards import ShardMap, apply_move, read_shard_map, rebalance_plan
from fleetbus.broker.topology import core_topology, declare_with_url
from fleetbus.cli.context import admin_api, console, endpoint, fail, settings
from fleetbus.cli.services import with_services
from fleetbus.schemas.routing import EXPRESS_QUEUE, EXPRESS_TYPES, ingest_shard_queue
from fleetbus.workers.recorder.summary import shorten
from fleetbus.workers.shards import SHARD_PREFIX, WORKER_PREFIX

if TYPE_CHECKING:
    from fleetbus.api.services.shards import Lease

app = typer.Typer(
    help="The ingest shards: which robots go through each, which worker consumes it.",
    invoke_without_command=True,
)


@dataclass(frozen=True)
class ShardState:
    shard: int
    queue: str
    robots: list[str]
    ready: int | None
    unacked: int | None
    worker: str | None

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def _queue_counts(api: ManagementAPI, vhost: str, queue: str) -> tuple[int | None, int | None]:
    """Ready and unacknowledged messages (the management API's figures, a few seconds old)."""
    try:
        found = api.get_queue(vhost, queue)
    except Exception:  # a shard queue not declared yet
        return None, None
    return found.get("messages_ready"), found.get("messages_unacknowledged")


def _states(api: ManagementAPI, vhost: str, shard_map: ShardMap, leases: list[Lease]) -> list[ShardState]:
    now = datetime.now(timezone.utc)
    holders = {lease.name: lease.holder for lease in leases if lease.live(now)}
    numbers = sorted({*range(shard_map.shards), *(s for bound in shard_map.bindings.values() for s in bound)})
    states = []
    for shard in numbers:
        queue = ingest_shard_queue(shard)
        robots = shard_map.robots_on(shard) + (list(shard_map.unassigned) if shard == 0 else [])
        ready, unacked = _queue_counts(api, vhost, queue)
        states.append(ShardState(shard, queue, robots, ready, unacked, holders.get(f"{SHARD_PREFIX}{shard}")))
    return states


def _leases() -> list[Lease]:
    return with_services(lambda services: services.shards.leases())


def _robots() -> list[str]:
    """The account registry's robots: the only names a shard is for."""
    return with_services(lambda services: services.shards.robots())


@app.callback()
def shards(
    ctx: typer.Context,
    as_json: Annotated[bool, typer.Option("--json", help="one JSON document")] = False,
) -> None:
    """Each shard's queue, robots, waiting messages and the worker consuming it."""
    if ctx.invoked_subcommand is not None:
        return
    config, ep = settings(), endpoint()
    vhost = vhost_of(ep.amqp_url)
    leases, robots = _leases(), _robots()
    with admin_api(ep) as api:
        shard_map = read_shard_map(api, vhost, config.ingest_shards, robots)
        states = _states(api, vhost, shard_map, leases)
        ready, unacked = _queue_counts(api, vhost, EXPRESS_QUEUE)
    # the worker that holds shard 0 consumes the express lane beside it
    express = {
        "queue": EXPRESS_QUEUE,
        "types": [t.value for t in EXPRESS_TYPES],
        "ready": ready,
        "unacked": unacked,
        "worker": next((state.worker for state in states if state.shard == 0), None),
    }
    now = datetime.now(timezone.utc)
    workers = sorted(
        lease.holder for lease in leases if lease.name.startswith(WORKER_PREFIX) and lease.live(now)
    )
    if as_json:
        document = {
            "shards": config.ingest_shards,
            "workers": workers,
            "states": [state.as_dict() for state in states],
            "express": express,
            "unassigned": list(shard_map.unassigned),
            "stray": shard_map.stray(),
        }
        console.print_json(json.dumps(document))
        return
    table = Table(title=f"{config.ingest_shards} ingest shards, {len(workers)} live workers")
    table.add_column("shard", justify="right")
    table.add_column("queue")
    table.add_column("robots", justify="right")
    table.add_column("names")
    table.add_column("ready", justify="right")
    table.add_column("unacked", justify="right")
    table.add_column("consumed by")
    for state in states:
        beyond = state.shard >= config.ingest_shards
        idle = "[red]no worker[/]" if state.robots else "none"
        table.add_row(
            str(state.shard) + (" (not configured)" if beyond else ""),
            state.queue,
            str(len(state.robots)),
            shorten(", ".join(state.robots), 40),
            "?" if state.ready is None else f"{state.ready:,}",
            "?" if state.unacked is None else f"{state.unacked:,}",
            state.worker or idle,
        )
    table.add_section()
    table.add_row(
        "express",
        EXPRESS_QUEUE,
        "all",
        ", ".join(express["types"]),
        "?" if ready is None else f"{ready:,}",
        "?" if unacked is None else f"{unacked:,}",
        express["worker"] or "[red]no worker[/]",
    )
    console.print(table)
    if shard_map.unassigned:
        console.print(f"bound to no shard, so in shard 0: {', '.join(shard_map.unassigned)}", highlight=False)
    if shard_map.stray():
        console.print(f"[yellow]to move[/] (`fleetbus shards rebalance`): {', '.join(shard_map.stray())}")


@app.command("rebalance")
def rebalance(
    dry_run: Annotated[bool, typer.Option("--dry-run", help="show the moves, make none")] = False,
    force: Annotated[
        bool, typer.Option("--force", help="move robots even while their shards hold messages")
    ] = False,
) -> None:
    """Spread the robots evenly over FLEETBUS_INGEST_SHARDS shards (after changing it, say).

    A robot moved while messages of its old shard wait could have them stored out of order, so by
    default the shards involved must be empty (stop the robots, or let the workers catch up).
    """
    config, ep = settings(), endpoint()
    vhost = vhost_of(ep.amqp_url)
    with admin_api(ep) as api:
        if not dry_run:  # a dry run changes nothing on the broker
            # every target shard's queue exists before robots are bound to it
            asyncio.run(
                declare_with_url(ep.amqp_url, [core_topology(config.ingest_shards, cluster=config.cluster)])
            )
        shard_map = read_shard_map(api, vhost, config.ingest_shards, _robots())
        moves = rebalance_plan(shard_map)
        if not moves:
            console.print(f"balanced: {shard_map.load()} robots on {config.ingest_shards} shards")
            return
        involved = sorted({shard for move in moves for shard in (*(move.bound or (0,)), move.target)})
        busy = {}
        for shard in involved:
            ready, unacked = _queue_counts(api, vhost, ingest_shard_queue(shard))
            if ready or unacked:
                busy[shard] = (ready or 0) + (unacked or 0)
        for move in moves:
            console.print(str(move), highlight=False)
        if dry_run:
            console.print(f"{len(moves)} moves (dry run: none made)")
            return
        if busy and not force:
            held = ", ".join(f"shard {shard} holds {count:,}" for shard, count in busy.items())
            fail(
                f"{held}: robots moved now could have those events stored after newer ones; wait until "
                "the shards are empty (the management API's counts lag a few seconds), or use --force"
            )
        for move in moves:
            apply_move(api, vhost, move)
        console.print(f"moved {len(moves)} robots: {read_shard_map(api, vhost, config.ingest_shards).load()}")
