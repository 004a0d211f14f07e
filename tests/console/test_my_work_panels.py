"""The live My work panels: one per user, rendered for the user as the latest page knew it (no
browser: what is kept, not what is drawn)."""

from __future__ import annotations

import asyncio
from dataclasses import replace
from datetime import datetime, timezone
from typing import Any

import pytest

import fleetbus.api.console.my_work as my_work_module
from fleetbus.api.console.my_work import MyWorkPanels
from fleetbus.schemas.roles import UserRole
from fleetbus.workers.store.users import User

NOW = datetime(2026, 1, 1, tzinfo=timezone.utc)


def test_a_users_panel_is_one_whatever_roles_it_had_and_renders_what_the_latest_page_knew(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    async def context(_: object, user: User) -> dict[str, Any]:
        return {"seen": (user.role.value, user.use_cases)}

    monkeypatch.setattr(my_work_module, "my_work", context)
    monkeypatch.setattr(my_work_module, "fragment", lambda _template, user, seen: repr(seen))
    panels = MyWorkPanels(service=None)  # type: ignore[arg-type]
    planner = User("plan1", UserRole.PLANNER, None, None, None, NOW, "test", NOW)

    async def run() -> list[list[str]]:
        shown = [await panels.of(planner)]
        shown.append(await panels.of(replace(planner, role=UserRole.CLIENT)))
        panels._renders["plan1"][1].want(1)  # news: the next page renders anew, in the interval
        shown.append(await panels.of(replace(planner, role=UserRole.CLIENT, use_cases=("survey",))))
        return shown

    assert asyncio.run(run()) == [
        ["('planner', None)"],
        ["('client', None)"],
        ["('client', ('survey',))"],
    ]
    assert len(panels._renders) == 1, "one panel per user, not one per role it ever had"
