"""The robot's FLEETBUS_LATE_AFTER_S: read as the service reads it, refused with its name when wrong."""

from __future__ import annotations

import pytest

from fleetbus.publishers.client import LATE_AFTER_VARIABLE, late_after_from_environment
from fleetbus.schemas.notifications import LATE_AFTER_S


def test_the_robot_reads_its_late_after_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(LATE_AFTER_VARIABLE, raising=False)
    assert late_after_from_environment() == LATE_AFTER_S
    monkeypatch.setenv(LATE_AFTER_VARIABLE, "1.5")
    assert late_after_from_environment() == 1.5
    for wrong in ("soon", "-1", "nan"):
        monkeypatch.setenv(LATE_AFTER_VARIABLE, wrong)
        with pytest.raises(ValueError, match=f"{LATE_AFTER_VARIABLE}: '{wrong}' is not a number"):
            late_after_from_environment()
