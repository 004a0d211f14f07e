"""Many robots at once: `fleetbus users add-many` makes each account as `users add` makes one
(permissions, topic permissions, exchanges, inbox, bindings, a shard), in one broker import."""

from __future__ import annotations

import asyncio
import re
import stat
from collections import Counter
from pathlib import Path

from fleetbus.broker.accounts import vhost_of
from fleetbus.broker.fleet import NewRobot, password_hash, provision_robots
from fleetbus.broker.shards import read_shard_map
from fleetbus.publishers.client import RobotClient
from fleetbus.schemas.routing import RobotKind
from tests.factories import status
from tests.support import Bus, wait_for
from tests.test_cli import fleetbus


def owned(bus: Bus, name: str) -> dict[str, object]:
    """What an account has on the broker, its name replaced so two accounts compare."""
    vhost = vhost_of(bus.admin_url)

    def plain(text: str) -> str:  # the account's name, and its shard's number (compared apart)
        return re.sub(r"^(fleetbus\.ingest\.events)\.\d+$", r"\1", text.replace(name, "NAME"))

    topic = [p for p in bus.api.topic_permissions(name) if p["vhost"] == vhost]
    bindings = [
        b for b in bus.api.list_bindings(vhost) if name in b["source"] + b["destination"] + b["routing_key"]
    ]
    permissions = bus.api.get_permissions(vhost, name) or {}
    return {
        "permissions": {k: plain(v) for k, v in permissions.items() if k != "user"},
        "topic": sorted((plain(p["exchange"]), p["write"], p["read"]) for p in topic),
        "bindings": sorted(
            (plain(b["source"]), plain(b["destination"]), b["destination_type"], plain(b["routing_key"]))
            for b in bindings
        ),
        "tags": bus.api.get_user(name)["tags"],
    }


def test_add_many_makes_each_robot_as_users_add_does_and_spreads_the_shards(bus: Bus, tmp_path: Path) -> None:
    bus.settings = bus.settings.updated(ingest_shards=4)
    names = tmp_path / "robots.txt"
    robots = [f"fleet{i:02d}" for i in range(12)]
    lines = [f"{n} warden" if n == "fleet00" else n for n in robots]
    names.write_text("# a team\n" + "\n".join(lines) + "\n")
    bus.accounts += robots
    urls = tmp_path / "urls.txt"
    made = fleetbus(bus, "users", "add-many", str(names), "--kind", "explorer", "--urls", str(urls))
    assert made.returncode == 0, made.stderr
    assert "amqp" not in made.stdout, "no URL on the screen"
    assert stat.S_IMODE(urls.stat().st_mode) == 0o600
    found = dict(line.split(" ", 1) for line in urls.read_text().splitlines())
    assert sorted(found) == robots
    one = bus.add("single1", kind=RobotKind.EXPLORER)  # as `users add` makes it
    assert owned(bus, "fleet05") == owned(bus, one.name)
    shards = read_shard_map(bus.api, vhost_of(bus.admin_url), 4)
    assert sorted(Counter(shards.shard_of(r) for r in robots).values()) == [3, 3, 3, 3]
    kinds = {r.name: r.kind for r in bus.with_store(lambda store: store.hazards.robots())}
    assert kinds["fleet00"] == "warden" and kinds["fleet05"] == "explorer"
    again = fleetbus(bus, "users", "add-many", str(names), "--urls", str(tmp_path / "again.txt"))
    assert again.returncode == 1 and "exist already" in again.stderr and "--rotate" in again.stderr
    robot = RobotClient(found["fleet05"], state_dir=bus.settings.robots_dir)
    bus.clients.append(robot)
    with bus.worker():
        robot.publish("status", status())
        wait_for(lambda: bus.count("status", "fleet05") == 1, what="its event stored")


def test_the_password_hash_is_rabbitmqs() -> None:
    """RabbitMQ's own example: salt 908D C60A, password ``test12``."""
    expected = "kI3GCqW5JLMJa4iX1lo7X4D6XbYqlLgxIs30+P6tENUV2POR"
    assert password_hash("test12", bytes.fromhex("908DC60A")) == expected


def test_a_batch_names_a_robot_once(bus: Bus) -> None:
    robots = [NewRobot("twice1"), NewRobot("twice1")]
    try:
        asyncio.run(provision_robots(bus.admin_url, bus.api, robots))
    except ValueError as error:
        assert "twice1" in str(error)
    else:
        raise AssertionError("a robot named twice was made")
