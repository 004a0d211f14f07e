"""The dashboard's My work panel is live, in a real browser on the real broker and store: a
mission filed for a client, or a robot an operator mounts, shows on their open dashboard without
a reload, whether the page watches the team (an operator's) or shows only the user's own work (a
client's); another user's open dashboard shows none of it."""

from __future__ import annotations

from datetime import datetime, timezone

from fleetbus.schemas.missions import MissionPlan
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from tests.console.support import Browser, running_console
from tests.support import Bus


def test_my_work_shows_new_missions_and_mounts_without_a_reload(bus: Bus, browser: Browser) -> None:
    with running_console(bus) as console:
        console.user("oper1", UserRole.OPERATOR)
        console.user("client1", UserRole.CLIENT)
        console.user("client2", UserRole.CLIENT)
        console.user("explorer1", UserRole.ROBOT, RobotKind.EXPLORER)
        service = console.service
        marked = "document.body.dataset.marker = 'not reloaded'"
        not_reloaded = "return document.body.dataset.marker"

        # a client's dashboard (its own work alone)
        console.log_in(browser, "client1")
        console.wait_live(browser)
        assert browser.find("#no-missions") and not browser.find("#team")
        browser.driver.execute_script(marked)

        async def file_missions() -> str:
            users = service.repositories.users
            client1, client2 = await users.get_user("client1"), await users.get_user("client2")
            assert client1 is not None and client2 is not None
            await service.missions.create(client2, "survey", "Not client1's", MissionPlan())
            mine = await service.missions.create(client1, "survey", "North yard", MissionPlan())
            return mine.mission_id

        mission_id = console.run(file_missions)
        browser.until(lambda: browser.find(f"#my-mission-{mission_id}"), "client1's new mission, live")
        assert browser.text("#my-missions-count") == "1", "client2's mission is not client1's work"
        assert "North yard" in browser.text(f"#my-mission-{mission_id}")
        assert browser.driver.execute_script(not_reloaded) == "not reloaded"
        assert browser.text("#my-broker-user") == "client1", "the broker login stays below the panel"

        # an operator's dashboard (which watches the team too): a robot mounted shows
        browser.reset()
        console.log_in(browser, "oper1")
        console.wait_live(browser)
        assert browser.find("#team") and not browser.find("#my-mount-explorer1")
        browser.driver.execute_script(marked)
        now = datetime.now(timezone.utc)
        console.run(lambda: service.repositories.channels.mount("explorer1", "oper1", mission_id, now))
        browser.until(lambda: browser.find("#my-mount-explorer1"), "the mount, live")
        assert mission_id in browser.text("#my-mount-explorer1")
        browser.until(
            lambda: browser.find(f"#my-mission-{mission_id}"), "the mission the operator now works on"
        )
        assert browser.driver.execute_script(not_reloaded) == "not reloaded"
        assert browser.console_errors() == []
