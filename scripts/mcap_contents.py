"""What an exported MCAP file holds, as a picture for the documentation: ``docs/images/ros/``.

    .venv/bin/python -m scripts.mcap_contents          # a few seconds; needs chromium for the PNG

A small recording made on the spot (no broker: a temporary SQLite recording): an explorer's map,
statuses and hazards, a warden's localisation, and a ROS 1 bag imported as the explorer's. It
is exported with ``export_mcap`` exactly as ``fleetbus export --mcap`` does, read back with the
``mcap`` reader and shown with rich: the channel table (topic, schema, messages), then messages
as Foxglove's own reader decodes them (``tests/peers/mcap_decode.js``: ``@mcap/core``,
``@foxglove/rosmsg``, ``@foxglove/rosmsg-serialization``; needs ``FLEETBUS_WITH_PEERS=1 bash
scripts/setup``): a Foxglove pose, a hazard's scene update, and an imported ROS 1 pose and image
from their native encoding. Written as ``mcap-contents.svg`` (rich's own rendering) and
``mcap-contents.png`` (the SVG in headless chromium).
"""

from __future__ import annotations

import argparse
import asyncio
import io
import json
import re
import subprocess
import tempfile
import uuid
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from rich.console import Console, Group
from rich.json import JSON
from rich.panel import Panel
from rich.table import Table

from fleetbus.schemas.envelope import EVENT_MODELS
from fleetbus.schemas.ros import ROS_SCHEMA_TYPE
from fleetbus.schemas.routing import EventType
from fleetbus.workers.recorder.bag_import import import_bag
from fleetbus.workers.recorder.mcap_export import export_mcap
from fleetbus.workers.recorder.queries import recorded_between
from fleetbus.workers.recorder.ros_native import RosSchema
from fleetbus.workers.store.recordings import RecordedMessage, RecordQuery
from fleetbus.workers.store.sqlite_recordings import SQLiteRecordingStore
from tests.factories import hazard, small_map, status
from tests.ros_bags import write_bag

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "docs" / "images" / "ros"
START = datetime(2026, 3, 2, 9, 30, tzinfo=timezone.utc)
EPOCH = "20260302T093000000Z-00c0ffee"
WIDTH = 118


def event(robot: str, type: EventType, seq: int, body: dict[str, Any]) -> RecordedMessage:
    at = START + timedelta(seconds=seq)
    envelope = EVENT_MODELS[type](
        message_id=uuid.UUID(int=seq + 1), robot_id=robot, epoch=EPOCH, seq=seq, sent_at=at, body=body
    )
    return RecordedMessage(
        key=f"{robot}-{seq}",
        type=type.value,
        recorded_at=at + timedelta(milliseconds=40),
        exchange=f"{robot}.events",
        routing_key=f"{robot}.{type.value}",
        user_id=robot,
        robot_id=robot,
        message_id=str(envelope.message_id),
        sent_at=at,
        seq=seq,
        known=True,
        document=json.loads(envelope.model_dump_json()),
    )


def recording() -> list[RecordedMessage]:
    made = [event("explorer1", EventType.MAP, 0, small_map(40, 30))]
    made += [event("warden1", EventType.LOCALISATION, 1, {"localised": True, "pose": {"x": 1.5, "y": 0.5}})]
    for i in range(3):
        made.append(event("explorer1", EventType.STATUS, 2 + 2 * i, status(90.0 - i)))
        made.append(event("explorer1", EventType.HAZARD, 3 + 2 * i, hazard(i, description=f"spill {i + 1}")))
    return made


async def export(folder: Path, target: Path) -> None:
    async with SQLiteRecordingStore(folder / "recording.sqlite3") as store:
        await store.write_recorded(recording())
        bag = folder / "drive.bag"
        write_bag(bag, "ros1", count=6)
        await import_bag(store, bag, "explorer1", 1024 * 1024)
        records = [r async for r in recorded_between(store, None, None)]
        schemas = [RosSchema.of(r.document) for r in await store.find_recorded(RecordQuery(ROS_SCHEMA_TYPE))]
    with target.open("wb") as stream:
        export_mcap(records, stream, ros_schemas={s.key: s for s in schemas if s is not None})


def render(path: Path, console: Console) -> None:
    with path.open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        counts = summary.statistics.channel_message_counts
        table = Table(title=f"fleetbus export --mcap {path.name}", title_justify="left")
        for column in ("topic", "schema", "encoding", "messages"):
            table.add_column(column, justify="right" if column == "messages" else "left")
        for channel_id, channel in sorted(summary.channels.items()):
            schema = summary.schemas[channel.schema_id]
            table.add_row(
                channel.topic,
                schema.name,
                f"{channel.message_encoding} / {schema.encoding}",
                str(counts.get(channel_id, 0)),
            )
    decoded = subprocess.run(
        ["node", str(ROOT / "tests" / "peers" / "mcap_decode.js"), str(path)],
        capture_output=True,
        text=True,
        check=True,
    )
    first: dict[str, Any] = {}
    for line in map(json.loads, decoded.stdout.splitlines()):
        if line["kind"] == "message" and line["schema"] not in first:
            first[line["schema"]] = line
    panels = []
    shown = ("foxglove.PoseInFrame", "foxglove.SceneUpdate", "geometry_msgs/PoseStamped", "sensor_msgs/Image")
    for name in shown:
        line = first[name]
        text = JSON.from_data(line["message"], indent=None).text
        text.no_wrap, text.overflow = False, "fold"
        title = f"{line['topic']}  ({name}, {line['encoding']}: decoded by Foxglove's reader)"
        panels.append(Panel(text, title=title, title_align="left"))
    console.print(Group(table, *panels))


def screenshot(svg: Path, png: Path) -> None:
    """The SVG at its own size (its viewBox) in headless chromium, saved as a PNG."""
    match = re.search(r'viewBox="0 0 ([0-9.]+) ([0-9.]+)"', svg.read_text())
    assert match, "rich writes a viewBox"
    width, height = (round(float(v)) for v in match.groups())
    with tempfile.TemporaryDirectory() as folder:
        page = Path(folder) / "page.html"
        page.write_text(
            f'<html><body style="margin:0;background:#fff"><img src="{svg.as_uri()}" '
            f'width="{width}" height="{height}"></body></html>'
        )
        subprocess.run(
            [
                "chromium",
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--hide-scrollbars",
                f"--screenshot={png}",
                f"--window-size={width},{height}",
                page.as_uri(),
            ],
            check=True,
            capture_output=True,
            timeout=120,
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as folder:
        target = Path(folder) / "run.mcap"
        asyncio.run(export(Path(folder), target))
        console = Console(record=True, width=WIDTH, force_terminal=True, file=io.StringIO())
        render(target, console)
    svg = args.out / "mcap-contents.svg"
    console.save_svg(str(svg), title="fleetbus export --mcap")
    png = args.out / "mcap-contents.png"
    screenshot(svg, png)
    print(f"wrote {svg.relative_to(ROOT)} and {png.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
