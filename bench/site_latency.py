"""A site's hazard latency with its link to central up, cut, and restored, in one run on one pair.

    .venv/bin/python -m bench.site_latency [--hazards 200] [--rate 1000]

Two private RabbitMQ nodes on loopback, a site and central (:func:`tests.sites.pair.open_pair`):
the site's shovels reach central through a TCP proxy the bench cuts. At the site run
`fleetbus worker --no-recorder` (a process of its own), a warden (:mod:`bench.warden`, a robot
process of its own, localised so the gate is open), four robots publishing ``--rate`` telemetry
events a second (:mod:`bench.telemetry`), and the explorer in this process, all robots of the
site forwarded to central. Telemetry, warden and worker run through all three phases:

- **up**: the uplink shovel running; every event the site accepts is also forwarded to central;
- **cut**: the proxy drops the link and refuses new connections (central unreachable); the
  uplink keeps what central will get later;
- **restored**: the link back; the shovel forwards the cut's backlog while the team works.

In each phase the explorer publishes ``--hazards`` hazards, 20 a second, and the warden's receipt
is timed from the publish call (one monotonic clock for every process). Between two hazards a raw
message goes through a queue on the site's node declared like the ingest queue (pika both ends):
one broker hop under the same load, the reference. Central's worker is not running: on this one
machine it would take CPU that a site machine in the field does not share with central (central's
node still takes the forwarded events). Nothing is asserted: the figures are printed and written
to ``bench/results/site-latency-<UTC time>.json``.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import pika
from rich.console import Console
from rich.table import Table

from bench.hazard_latency import HAZARD_RATE, LOADERS, PING_QUEUE, Arrivals, ping_receiver, publish_paced
from bench.processes import worker_process
from bench.raw import declare_queue, ingest_queue_arguments
from bench.report import load_average, machine
from bench.results import percentile, save
from bench.scenario import Figures
from bench.telemetry import TelemetryLoad
from bench.warden import WardenProcess
from fleetbus.dev.local_node import LocalNode
from fleetbus.schemas.routing import RobotKind
from tests.sites.pair import SitePair, open_pair
from tests.support import wait_for

PHASES = ("up", "cut", "restored")
QUANTILES = (50, 95, 99)


def measure(
    pair: SitePair, count: int, rate: float, show: Callable[[str], None] = lambda text: None
) -> dict[str, Figures]:
    """Each phase's figures: ``count`` hazards under ``rate`` telemetry events a second at the site."""
    site = pair.site
    explorer = site.robot(pair.add_robot("bench-explorer", RobotKind.EXPLORER))
    warden_url = pair.add_robot("bench-warden", RobotKind.WARDEN).amqp_url
    loaders = [pair.add_robot(f"bench-telemetry{i}", RobotKind.EXPLORER).amqp_url for i in range(LOADERS)]
    declare_queue(site.admin_url, ingest_queue_arguments(), PING_QUEUE)
    found: dict[str, Figures] = {}
    with worker_process(site, "--no-recorder"), WardenProcess(site, warden_url) as warden:
        wait_for(lambda: all(w.localised for w in site.with_store(lambda r: r.hazards.robots("warden"))))
        wait_for(lambda: pair.uplink_state() == "running", 60, "the uplink shovel running")
        ping = pika.BlockingConnection(pika.URLParameters(site.admin_url))
        with (
            TelemetryLoad(site, loaders, rate) as load,
            Arrivals(ping_receiver(site.admin_url), "ping") as pings,
        ):
            for k, phase in enumerate(PHASES):
                changed = _change_link(pair, phase)
                waiting_before = pair.uplink_waiting()
                show(f"{phase}: {count} hazards at {HAZARD_RATE}/s under {rate:,.0f} telemetry events/s")
                paced = publish_paced(explorer, ping.channel(), range(k * count, (k + 1) * count))
                warden.wait((k + 1) * count, 60)
                pings.wait((k + 1) * count, 60)
                hazard_ms = [1000 * (warden.at[i] - sent) for i, sent in paced.sent.items()]
                ping_ms = [1000 * (pings.at[i] - pinged) for i, pinged in paced.pinged.items()]
                found[phase] = {
                    **{f"hazard p{q} ms": percentile(hazard_ms, q) for q in QUANTILES},
                    "hazard max ms": max(hazard_ms),
                    **{f"raw hop p{q} ms": percentile(ping_ms, q) for q in QUANTILES},
                    "hazard p50 in raw hops": percentile(hazard_ms, 50) / percentile(ping_ms, 50),
                    "explorer's publish p50 ms": percentile([1000 * s for s in paced.confirmed], 50),
                    "link changed s": changed,
                    "uplink waiting before": float(waiting_before),
                    "uplink waiting after": float(pair.uplink_waiting()),
                }
            show("restored: the uplink draining")
            drained = wait_for_seconds(lambda: pair.uplink_waiting() == 0, 300, "the uplink drained")
            found["restored"]["uplink drained s after the hazards"] = drained
        ping.close()
    found["run"] = {"telemetry events/s": load.rate}
    return found


def _change_link(pair: SitePair, phase: str) -> float:
    """Cut or restore the link for ``phase``; seconds until the uplink shovel saw it."""
    started = time.monotonic()
    if phase == "cut":
        pair.link.cut()
        wait_for(lambda: pair.uplink_state() != "running", 60, "the uplink shovel to lose central")
    elif phase == "restored":
        pair.link.restore()
        wait_for(lambda: pair.uplink_state() == "running", 60, "the uplink shovel to reach central again")
    return time.monotonic() - started


def wait_for_seconds(condition: Callable[[], bool], timeout: float, what: str) -> float:
    started = time.monotonic()
    wait_for(condition, timeout, what, interval=0.2)
    return time.monotonic() - started


def ratios(found: dict[str, Figures]) -> Figures:
    """Cut (and restored) over up, for the hazard's quantiles and the raw hop's median."""
    up = found["up"]
    figures = [f"hazard p{q} ms" for q in QUANTILES] + ["raw hop p50 ms"]
    return {
        f"{phase} / up, {figure.removesuffix(' ms')}": found[phase][figure] / up[figure]
        for phase in ("cut", "restored")
        for figure in figures
    }


def table(found: dict[str, Figures], title: str) -> Table:
    shown = Table(title=title)
    shown.add_column("figure")
    for phase in PHASES:
        shown.add_column(f"link {phase}", justify="right")
    shown.add_column("cut / up", justify="right")
    for figure in found["up"]:
        values = [found[phase].get(figure) for phase in PHASES]
        ratio = (
            found["cut"][figure] / found["up"][figure]
            if "hazard p" in figure or "raw hop" in figure
            else None
        )
        shown.add_row(
            figure,
            *("" if value is None else f"{value:,.2f}" for value in values),
            "" if ratio is None else f"{ratio:.2f}",
        )
    for figure in ("uplink drained s after the hazards",):
        shown.add_row(figure, "", "", f"{found['restored'][figure]:,.1f}", "")
    return shown


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--hazards", type=int, default=200, help="hazards in each phase (20 a second)")
    parser.add_argument("--rate", type=float, default=1000, help="telemetry events a second at the site")
    parser.add_argument("--out", type=Path, default=Path("bench/results"), help="where the JSON goes")
    args = parser.parse_args()
    console = Console()
    command = " ".join([".venv/bin/python -m bench.site_latency", *map(shlex.quote, sys.argv[1:])])
    load_before = load_average()
    with tempfile.TemporaryDirectory(prefix="fleetbus-bench-site-latency-") as folder:
        base = Path(folder)
        nodes = [LocalNode(base / name / "broker") for name in ("site", "central")]
        try:
            for node in nodes:
                node.up()
            with open_pair(*nodes, base / "pair") as pair:
                where = machine(pair.site.api, pair.site.endpoint)
                found = measure(
                    pair, args.hazards, args.rate, lambda text: console.print(text, highlight=False)
                )
        finally:
            for node in nodes:
                node.kill()  # throwaway: no clean shutdown's seconds
                node.down()
    meta = {"command": command, "load before": load_before, "load after": load_average(), "machine": where}
    console.print(
        table(
            found,
            f"a site's hazard to its warden, {args.hazards} hazards a phase, "
            f"{found['run']['telemetry events/s']:,.0f} telemetry events/s",
        )
    )
    for name, value in ratios(found).items():
        console.print(f"{name}: {value:.2f}", highlight=False)
    console.print(f"load average before {load_before}, after {meta['load after']}", highlight=False)
    path = save(args.out, "site-latency", {**meta, "phases": found, "ratios": ratios(found)})
    console.print(f"wrote {path}")


if __name__ == "__main__":
    main()
