"""The main job: the demo scenario ends with everything stored and delivered."""

from __future__ import annotations

from pathlib import Path

from rich.console import Console

from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.schemas.roles import UserRole
from fleetbus.settings import load_settings
from fleetbus.workers.store import run_with_repositories
from fleetbus_dev.demo import TEAM, WARDENS, run_demo


def test_demo_scenario(endpoint: BrokerEndpoint, tmp_path: Path) -> None:
    settings = load_settings().updated(data_dir=tmp_path)
    report = run_demo(
        settings,
        endpoint,
        Console(file=open(tmp_path / "out.txt", "w")),
        hazards=5,
        telemetry=5,
        map_size=1500,
    )
    assert report.ok, report.steps
    assert report.stored == report.published
    assert report.recorded == report.published, "the recorder ran alongside and kept every message"
    assert report.published["hazard"] == 7 and report.published["map"] == 1
    for warden in WARDENS:
        assert report.delivered[warden] == {"hazard": 7, "map": 1}
    assert report.dead_letters == 0
    assert report.steps[0][0] == "2 hazards detected before the wardens localised"
    # its robots were made through the accounts service: recorded in the demo's registry
    demo_settings = settings.updated(data_dir=tmp_path / "demo", mongodb_url=None)
    users = run_with_repositories(demo_settings, lambda repos: repos.users.users())
    made = {(user.name, user.role, user.kind, user.broker_secret is not None) for user in users}
    assert made == {(name, UserRole.ROBOT, kind.value, True) for name, kind in TEAM}
