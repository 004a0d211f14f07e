"""Beacons and the guide robot against the real broker: sightings, stranded people, the next goal."""

from __future__ import annotations

import asyncio
import json
import math
from pathlib import Path

import pytest
import yaml

from fleetbus.api.services.beacons import beacons_of
from fleetbus.api.services.errors import BadRequest
from fleetbus.broker.accounts import Role, provision_account
from fleetbus.publishers.rpc import ServiceRefused
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.beacons import Beacon
from tests.support import Bus, wait_for
from tests.test_cli import fleetbus


def sighting(beacon_id: str, rssi: int, x: float = 0.0) -> dict:
    return {"beacon_id": beacon_id, "rssi": rssi, "pose": {"x": x, "y": 1.0}}


def test_sightings_stranded_people_and_the_guides_goal(bus: Bus, tmp_path: Path) -> None:
    registry = tmp_path / "beacons.yaml"
    b1, b2 = {"id": "b1", "x": 1, "y": 2, "label": "room 101"}, {"id": "b2", "x": 8, "y": 3, "label": "lab"}
    registry.write_text(yaml.safe_dump([b1, b2]))
    loaded = fleetbus(bus, "beacons", "load", str(registry))
    assert (loaded.returncode, loaded.stdout) == (0, "2 beacons in the registry\n"), loaded.stderr
    guide = bus.robot(bus.add("guide1", kind=RobotKind.GUIDE))
    with bus.worker():
        guide.publish_many([("beacon", sighting("b2", -70, 7.0)), ("beacon", sighting("b1", -60, 1.5))])
        guide.publish_many([("beacon", sighting("b2", -65, 7.5)), ("beacon", sighting("b9", -80))])
        wait_for(lambda: bus.count("beacon") == 4, what="4 sightings stored")

        people = guide.stranded(minutes=5)
        assert [p["beacon_id"] for p in people] == ["b2", "b1", "b9"], "first heard first"
        b2 = people[0]
        assert (b2["label"], b2["location"], b2["sightings"], b2["last_rssi"]) == (
            "lab",
            {"x": 8.0, "y": 3.0},
            2,
            -65,
        )
        assert b2["seen_by"] == "guide1" and b2["robot_pose"]["x"] == 7.5
        assert people[2]["location"] is None, "an unregistered beacon is still reported"
        listed = fleetbus(bus, "beacons", "stranded", "--since", "5m", "--json")
        assert listed.returncode == 0, listed.stderr
        assert json.loads(listed.stdout) == people, "the command line reads the same registry and sightings"

        assert guide.beacon_goal()["beacon_id"] == "b2"
        guide.beacon_visited("b2")
        assert guide.beacon_goal()["beacon_id"] == "b1"
        assert guide.beacon_info("b1") == {
            "beacon_id": "b1",
            "x": 1.0,
            "y": 2.0,
            "label": "room 101",
            "visited_at": None,
        }
        with pytest.raises(ServiceRefused, match="no beacon 'b7'"):
            guide.beacon_info("b7")


def test_a_look_further_back_than_the_bound_is_refused_naming_it(bus: Bus) -> None:
    """Each sighting in the window is read into memory: the window is bounded, the same through the
    robot client's services and the command line."""
    bus.settings = bus.settings.updated(beacon_window_max_minutes=30.0)
    bounded = {"FLEETBUS_BEACON_WINDOW_MAX_MINUTES": "30"}
    refusal = r"looked at 30 minutes back at most \(FLEETBUS_BEACON_WINDOW_MAX_MINUTES\), not "
    guide = bus.robot(bus.add("guide1", kind=RobotKind.GUIDE))
    with bus.worker():
        assert guide.stranded(minutes=30) == [] and guide.beacon_goal(minutes=30) is None
        with pytest.raises(ServiceRefused, match=refusal + "31"):
            guide.stranded(minutes=31)
        with pytest.raises(ServiceRefused, match=refusal + "10,000,000$"):
            guide.beacon_goal(minutes=10_000_000)
    listed = fleetbus(bus, "beacons", "stranded", "--since", "2h", env=bounded)
    assert listed.returncode != 0 and "30 minutes back at most" in " ".join(listed.stderr.split())
    assert fleetbus(bus, "beacons", "stranded", "--since", "20m", env=bounded).returncode == 0


def test_sighting_from_an_unknown_robot_is_dead_lettered(bus: Bus) -> None:
    # a broker account the team's registry does not know
    stranger = asyncio.run(provision_account(bus.admin_url, bus.api, "stranger1", Role.ROBOT))
    bus.accounts.append("stranger1")
    guide = bus.robot(bus.add("guide1", kind=RobotKind.GUIDE))
    intruder = bus.robot(stranger)
    with bus.worker():
        intruder.publish("beacon", sighting("b1", -50))
        guide.publish("beacon", sighting("b1", -55))
        wait_for(lambda: bus.count("beacon") == 1, what="the guide's sighting stored")
        [letter] = wait_for(lambda: bus.dead_letters(), what="the stranger's sighting dead-lettered")
    assert (letter.reason, letter.user_id) == ("unknown-robot", "stranger1")
    assert "not a registered robot" in letter.detail
    assert [r.robot_id for r in bus.find()] == ["guide1"]


def test_a_beacon_that_is_not_at_a_finite_place_is_refused_and_nothing_of_its_file_stored(
    stored_bus: Bus, tmp_path: Path
) -> None:
    registry = tmp_path / "beacons.yaml"
    registry.write_text("- {id: b1, x: 1, y: 2}\n- {id: b2, x: .nan, y: 2}\n- {id: b3, x: 3, y: 4}\n")
    loaded = fleetbus(stored_bus, "beacons", "load", str(registry))
    assert loaded.returncode == 2, loaded.stderr
    assert f"{registry}: beacon 2: x must be a finite number, not nan" in " ".join(loaded.stderr.split())
    assert stored_bus.with_store(lambda store: store.beacons.beacons()) == [], "no beacon of the file stored"


@pytest.mark.parametrize(
    ("entries", "detail"),
    [
        ({"id": "b1", "x": 1, "y": 2}, "expected a list of beacons with id, x, y and label"),
        ([{"id": "b1", "x": 1, "y": 2}, {"id": "b2", "x": 1}], "beacon 2: y is missing"),
        ([{"id": "b1", "x": "east", "y": 2}], "beacon 1: x must be a valid number, unable to parse string"),
        ([{"id": "b1", "x": 1, "y": "NaN"}], "beacon 1: y must be a finite number, not 'NaN'"),
        ([{"id": "b1", "x": 0, "y": 0}, {"id": "b2", "x": -math.inf, "y": 0}], "beacon 2: x must be"),
        ([{"id": "b1", "x": 1, "y": "1e999"}], "beacon 1: y must be a finite number, not '1e999'"),
        (["b1"], "beacon 1: expected {id, x, y, label}, not 'b1'"),
    ],
)
def test_a_beacon_list_that_is_not_one_is_refused_whole_naming_the_first_bad_entry(
    entries: object, detail: str
) -> None:
    with pytest.raises(BadRequest) as refused:
        beacons_of(entries)
    assert refused.value.detail.startswith(detail)


def test_a_beacon_list_gives_each_beacon_its_label_or_none() -> None:
    assert beacons_of([{"id": 7, "x": 1, "y": "2.5", "label": "hall"}, {"id": "b2", "x": 0, "y": 0}]) == [
        Beacon("7", 1.0, 2.5, "hall"),
        Beacon("b2", 0.0, 0.0, ""),
    ]
