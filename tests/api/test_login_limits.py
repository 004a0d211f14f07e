"""The failed-login counts take memory for the last window's failures only, however many
addresses and names tried (no broker: the limits live in the API process)."""

from __future__ import annotations

import time

from fleetbus.api.services.login_limits import LoginLimits


def test_windows_with_no_failure_left_are_forgotten_and_a_name_no_account_can_have_takes_one_key() -> None:
    limits = LoginLimits("5 per 1 second", "20 per 1 second")
    for n in range(200):
        limits.failed(f"guess{n}", f"10.0.{n // 250}.{n % 250}")
        limits.failed("x" * 10_000 + str(n), "10.9.9.9")  # no account has such a name
    assert limits.storage.windows() == 200 + 200 + 2, "an address, a (name, address), one for bad names"
    assert limits.storage.forget_expired(time.time() + 2) == 402
    assert limits.storage.windows() == 0
    assert limits.storage.locks == {}


def test_a_window_still_holding_a_failure_is_kept_and_still_counts() -> None:
    limits = LoginLimits("2 per 1 minute", "20 per 1 minute")
    limits.failed("warden1", "10.0.0.1")
    limits.failed("warden1", "10.0.0.1")
    assert limits.storage.forget_expired() == 0
    assert limits.storage.windows() == 2
    limits.succeeded("warden1", "10.0.0.1")
    assert limits.storage.windows() == 1, "a login that succeeds clears its account's window"
