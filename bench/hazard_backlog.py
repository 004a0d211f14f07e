"""Hazards while the team's backlog drains: the explorer's publish to both wardens' receipt.

    .venv/bin/python -m bench.hazard_backlog [--runs 3] [--quick]

After an outage every robot drains its outbox at once, which is when the worker is busiest and a
hazard matters most. Five robots, in a process of their own (:mod:`bench.backlog`), start with
6,000 status events each in their outboxes and drain them together. Once 3,000 of them wait in
the ingest shard (the worker is stopped meanwhile, as it is while central comes back, so a fast
worker cannot empty the shard first), `fleetbus worker --no-recorder` starts in another process and
the explorer (in this process) publishes 20 hazards, 10 a second, to two wardens, each a robot process
of its own (:mod:`bench.warden`), localised beforehand so the gate is open. A hazard's latency is
the later of the two wardens' receipts. Half-way between two hazards a raw message crosses one
queue declared like the ingest queue (pika both ends): one broker hop under the same load, in the
same run, which the hazard is measured in (``hazard p99 in raw hops``: its p99 over the hop's
median).

The run checks that the hazards came while the backlog waited (``backlog ahead of each hazard``:
status events ready in the shard when it was published) and ends with every event stored once.
"""

from __future__ import annotations

import sys

from bench.backlog import Backlog
from bench.hazard_latency import STAGES, Arrivals, ping_receiver, publish_paced
from bench.processes import ConsumerCount, worker_process
from bench.raw import declare_queue, ingest_queue_arguments
from bench.results import percentile
from bench.scenario import Context, Figures
from bench.warden import WardenProcess
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.routing import INGEST_QUEUE, RobotKind
from tests.support import wait_for

PING_QUEUE = "bench.ping"
ROBOTS = 5
PER_ROBOT = 6_000
HAZARDS = 20
RATE = 10
WARDENS = 2
#: Status events that wait in the shard before the first hazard goes.
AHEAD = 3_000


class ShardDepth(ConsumerCount):
    """Messages ready in a queue, asked over one connection."""

    def ready(self) -> int:
        if self._channel is None or not self._channel.is_open:
            self._channel = self._connection.channel()
        return self._channel.queue_declare(self._queue, passive=True).method.message_count


def measure(context: Context, per_robot: int = PER_ROBOT, hazards: int = HAZARDS) -> Figures:
    """``hazards`` hazards while ``ROBOTS`` robots drain ``per_robot`` status events each."""
    total = ROBOTS * per_robot
    with context.bus() as bus:
        explorer = bus.robot(bus.add("bench-explorer", kind=RobotKind.EXPLORER))
        wardens = [bus.add(f"bench-warden{i}", kind=RobotKind.WARDEN).amqp_url for i in range(WARDENS)]
        loaders = [bus.add(f"bench-backlog{i}").amqp_url for i in range(ROBOTS)]
        declare_queue(bus.admin_url, ingest_queue_arguments(), PING_QUEUE)
        context.show(f"{ROBOTS} robots filling their outboxes with {total:,} status events")
        with (
            Backlog(bus, loaders, per_robot) as backlog,
            WardenProcess(bus, wardens[0]) as first,
            WardenProcess(bus, wardens[1]) as second,
        ):
            with worker_process(bus, "--no-recorder"):  # stores the wardens' localisations: the gate opens
                wait_for(
                    lambda: all(w.localised for w in bus.with_store(lambda r: r.hazards.robots("warden")))
                )
            depth = ShardDepth(bus.admin_url, INGEST_QUEUE)
            ahead: list[int] = []
            ping = blocking_connection(bus.admin_url)
            try:
                context.show(f"{total:,} status events draining")
                backlog.go()
                # the backlog waits in the shard before the worker comes back, however fast it is
                wait_for(lambda: depth.ready() >= min(AHEAD, total // 2), 120, "the backlog in the shard")
                with worker_process(bus, "--no-recorder"):
                    with Arrivals(ping_receiver(bus.admin_url), "ping") as pings:
                        context.show(f"{hazards} hazards at {RATE}/s while the backlog drains")
                        paced = publish_paced(
                            explorer,
                            ping.channel(),
                            range(hazards),
                            RATE,
                            lambda i: ahead.append(depth.ready()),
                        )
                        first.wait(hazards, 120)
                        second.wait(hazards, 120)
                        pings.wait(hazards, 60)
                    drained_s = backlog.wait()
                    context.show("the worker storing the rest of the backlog")
                    wait_for(lambda: bus.count("status") >= total, 600, f"{total:,} status events stored")
            finally:
                depth.close()
                ping.close()
        stored = bus.count("status"), bus.count("hazard")
        if stored != (total, hazards):
            raise AssertionError(f"stored {stored[0]} status and {stored[1]} hazard events")
    hazard_ms = [1000 * (max(first.at[i], second.at[i]) - paced.sent[i]) for i in paced.sent]
    ping_ms = [1000 * (pings.at[i] - paced.pinged[i]) for i in paced.pinged]
    hop = percentile(ping_ms, 50)
    stages = list(first.stages.values()) + list(second.stages.values())
    return {
        "hazard p50 ms": percentile(hazard_ms, 50),
        "hazard p99 ms": percentile(hazard_ms, 99),
        "hazard max ms": max(hazard_ms),
        "raw hop p50 ms": hop,
        "raw hop p99 ms": percentile(ping_ms, 99),
        "hazard p50 in raw hops": percentile(hazard_ms, 50) / hop,
        "hazard p99 in raw hops": percentile(hazard_ms, 99) / hop,
        **{
            f"{stage} p50 ms": percentile([1000 * times[k] for times in stages], 50)
            for k, stage in enumerate(STAGES)
        },
        **{f"{stage} max ms": max(1000 * times[k] for times in stages) for k, stage in enumerate(STAGES)},
        "backlog ahead of each hazard, min": min(ahead),
        "robots' drain s": drained_s,
    }


def figures(context: Context) -> Figures:
    return measure(context, context.size(PER_ROBOT, PER_ROBOT // 3), context.size(HAZARDS, HAZARDS))


if __name__ == "__main__":
    from bench.suite import main

    sys.exit(main(["--only", "hazard-backlog", *sys.argv[1:]]))
