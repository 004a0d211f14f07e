"""Settings read from the environment, with the defaults the README documents.

Every component reads its configuration through :func:`load_settings` so that one place
says which variable means what.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from schemas.notifications import LATE_AFTER_S

DEFAULT_DATA_DIR = ".fleetbus"
DEFAULT_MAX_MESSAGE_BYTES = 1024 * 1024
DEFAULT_BATTERY_LOW_PERCENT = 20.0
DEFAULT_RECORDER_KEEP = "*=1GB"
DEFAULT_TOKEN_MINUTES = 60.0
DEFAULT_LATE_AFTER_S = LATE_AFTER_S
DEFAULT_STALE_AFTER_S = 60.0
DEFAULT_INGEST_SHARDS = 1
DEFAULT_BROKER_WAIT_S = 60.0
DEFAULT_API_HASH_THREADS = 1
DEFAULT_API_ACCOUNT_FAILURES = "5 per 5 minutes"
DEFAULT_API_ADDRESS_FAILURES = "20 per 5 minutes"
MAX_INGEST_SHARDS = 64
DEFAULT_EVENTS_KEEP = "*=30d"
DEFAULT_DUPLICATES_KEEP = "30d"
DEFAULT_DISCARDS_KEEP = "30d"
DEFAULT_MAP_VERSIONS_KEEP = 10
DEFAULT_MAP_STAGING_TTL = "1h"
DEFAULT_DEAD_LETTERS_MAX = "100000 1GB"
DEFAULT_INBOX_MAX = "10000 100MB"
DEFAULT_FIELD_INDEXES_MAX = 32
DEFAULT_PRUNE_EVERY_S = 60.0


def _words(value: str | None) -> tuple[str, ...]:
    """A list in one variable: separated by commas or spaces."""
    return tuple(word for word in (value or "").replace(",", " ").split() if word)


@dataclass(frozen=True)
class Settings:
    data_dir: Path
    """Everything fleetbus keeps on this machine: private broker node, credentials, SQLite store."""
    amqp_url: str | None
    """Administrator URL of an existing broker; ``None`` means the private node under ``data_dir``."""
    management_url: str | None
    """Management HTTP API of that broker; derived from ``amqp_url`` when unset."""
    mongodb_url: str | None
    """MongoDB connection string; ``None`` selects the embedded SQLite store."""
    max_message_bytes: int
    """Bodies larger than this are dead-lettered by the workers."""
    battery_low_percent: float = DEFAULT_BATTERY_LOW_PERCENT
    """A status below this battery level notifies the operators (once per crossing)."""
    recorder_include: tuple[str, ...] = ()
    """Routing-key patterns the recorder keeps (all when empty)."""
    recorder_exclude: tuple[str, ...] = ()
    """Routing-key patterns the recorder drops."""
    recorder_keep: tuple[str, ...] = (DEFAULT_RECORDER_KEEP,)
    """Retention per type: ``status=7d``, ``map_chunk=500MB``, ``tf=100000``, ``*=1GB``."""
    api_secret: str | None = None
    """The HTTP API's master secret (signs tokens, encrypts stored broker passwords); ``None``:
    a random one kept in ``data_dir/api/secret``. Every replica of the API needs the same."""
    token_minutes: float = DEFAULT_TOKEN_MINUTES
    """How long a login token is valid."""
    late_after_s: float = DEFAULT_LATE_AFTER_S
    """A notification that reaches its robots this long after the event was sent is flagged late."""
    ingest_shards: int = DEFAULT_INGEST_SHARDS
    """Ingest shard queues; each robot's events go through one, and the workers share them."""
    service_url: str | None = None
    """Where the worker and the recorder log in, as the ``fleetbus`` service account (the password,
    when the URL has none, is the one ``fleetbus setup`` keeps in ``accounts_dir``)."""
    broker_wait_s: float = DEFAULT_BROKER_WAIT_S
    """How long a command waits, with backoff, for a configured broker that does not answer."""
    api_hash_threads: int = DEFAULT_API_HASH_THREADS
    """Password hashes the API computes at once (each on a thread, off the event loop)."""
    api_account_failures: str = DEFAULT_API_ACCOUNT_FAILURES
    """Failed logins to one account from one address before it gets 429 (``limits`` notation)."""
    api_address_failures: str = DEFAULT_API_ADDRESS_FAILURES
    """Failed logins from one address, to any account, before it gets 429."""
    stale_after_s: float = DEFAULT_STALE_AFTER_S
    """A robot silent this long (no event of any type) is shown stale in ``fleetbus team``."""
    events_keep: tuple[str, ...] = (DEFAULT_EVENTS_KEEP,)
    """The event log's retention per type, as ``recorder_keep`` but by age or number of records."""
    duplicates_keep: str = DEFAULT_DUPLICATES_KEEP
    """How long (``30d``) or how many (``100000``) of the duplicates register to keep."""
    discards_keep: str = DEFAULT_DISCARDS_KEEP
    """How long or how many of the beacon discard log to keep."""
    map_versions_keep: int = DEFAULT_MAP_VERSIONS_KEEP
    """Map versions kept per robot (the newest), besides any version a robot is fetching."""
    map_staging_ttl: str = DEFAULT_MAP_STAGING_TTL
    """Staged map chunks whose map event has not come this long after their last chunk are deleted."""
    dead_letters_max: tuple[str, ...] = tuple(DEFAULT_DEAD_LETTERS_MAX.split())
    """The dead-letter queue's length: a number of messages and/or a size; the oldest go first."""
    inbox_max: tuple[str, ...] = tuple(DEFAULT_INBOX_MAX.split())
    """Each inbox's length: a number of messages and/or a size; the oldest go first."""
    field_indexes_max: int = DEFAULT_FIELD_INDEXES_MAX
    """Field indexes the recording keeps per type for queries; the least recently used go first."""
    prune_every_s: float = DEFAULT_PRUNE_EVERY_S
    """Seconds between two rounds of the worker's background pruning."""

    @property
    def sqlite_path(self) -> Path:
        return self.data_dir / "store.sqlite3"

    @property
    def recording_path(self) -> Path:
        """The recorder's SQLite file (apart from the event log's, so neither waits for the other)."""
        return self.data_dir / "recording.sqlite3"

    @property
    def broker_dir(self) -> Path:
        return self.data_dir / "broker"

    @property
    def accounts_dir(self) -> Path:
        return self.data_dir / "accounts"

    @property
    def robots_dir(self) -> Path:
        return self.data_dir / "robots"

    @property
    def api_dir(self) -> Path:
        return self.data_dir / "api"


def load_settings(environ: Mapping[str, str] | None = None) -> Settings:
    env = os.environ if environ is None else environ
    settings = Settings(
        data_dir=Path(env.get("FLEETBUS_DATA_DIR") or DEFAULT_DATA_DIR).resolve(),
        amqp_url=env.get("FLEETBUS_AMQP_URL") or None,
        management_url=env.get("FLEETBUS_MANAGEMENT_URL") or None,
        mongodb_url=env.get("FLEETBUS_MONGODB_URL") or None,
        max_message_bytes=int(env.get("FLEETBUS_MAX_MESSAGE_BYTES") or DEFAULT_MAX_MESSAGE_BYTES),
        battery_low_percent=float(env.get("FLEETBUS_BATTERY_LOW_PERCENT") or DEFAULT_BATTERY_LOW_PERCENT),
        recorder_include=_words(env.get("FLEETBUS_RECORDER_INCLUDE")),
        recorder_exclude=_words(env.get("FLEETBUS_RECORDER_EXCLUDE")),
        recorder_keep=_words(env.get("FLEETBUS_RECORDER_KEEP")) or (DEFAULT_RECORDER_KEEP,),
        api_secret=env.get("FLEETBUS_API_SECRET") or None,
        token_minutes=float(env.get("FLEETBUS_API_TOKEN_MINUTES") or DEFAULT_TOKEN_MINUTES),
        late_after_s=float(env.get("FLEETBUS_LATE_AFTER_S") or DEFAULT_LATE_AFTER_S),
        ingest_shards=_shards(env.get("FLEETBUS_INGEST_SHARDS")),
        service_url=env.get("FLEETBUS_SERVICE_URL") or None,
        broker_wait_s=_positive("FLEETBUS_BROKER_WAIT_S", env, DEFAULT_BROKER_WAIT_S, float),
        api_hash_threads=int(_positive("FLEETBUS_API_HASH_THREADS", env, DEFAULT_API_HASH_THREADS, int)),
        api_account_failures=_rate("FLEETBUS_API_ACCOUNT_FAILURES", env, DEFAULT_API_ACCOUNT_FAILURES),
        api_address_failures=_rate("FLEETBUS_API_ADDRESS_FAILURES", env, DEFAULT_API_ADDRESS_FAILURES),
        stale_after_s=float(env.get("FLEETBUS_STALE_AFTER_S") or DEFAULT_STALE_AFTER_S),
        **_bounds(env),
    )
    from workers.bounds import bounds  # the bounds' grammar lives with the rules that apply them

    bounds(settings)  # a bound that does not parse stops the process now, naming its variable
    return settings


def _bounds(env: Mapping[str, str]) -> dict[str, Any]:
    """The settings that bound what grows (checked by :func:`workers.bounds.bounds`)."""
    return {
        "events_keep": _words(env.get("FLEETBUS_EVENTS_KEEP")) or (DEFAULT_EVENTS_KEEP,),
        "duplicates_keep": env.get("FLEETBUS_DUPLICATES_KEEP") or DEFAULT_DUPLICATES_KEEP,
        "discards_keep": env.get("FLEETBUS_DISCARDS_KEEP") or DEFAULT_DISCARDS_KEEP,
        "map_versions_keep": int(
            _positive("FLEETBUS_MAP_VERSIONS_KEEP", env, DEFAULT_MAP_VERSIONS_KEEP, int)
        ),
        "map_staging_ttl": env.get("FLEETBUS_MAP_STAGING_TTL") or DEFAULT_MAP_STAGING_TTL,
        "dead_letters_max": _words(env.get("FLEETBUS_DEAD_LETTERS_MAX"))
        or tuple(DEFAULT_DEAD_LETTERS_MAX.split()),
        "inbox_max": _words(env.get("FLEETBUS_INBOX_MAX")) or tuple(DEFAULT_INBOX_MAX.split()),
        "field_indexes_max": int(
            _positive("FLEETBUS_FIELD_INDEXES_MAX", env, DEFAULT_FIELD_INDEXES_MAX, int)
        ),
        "prune_every_s": _positive("FLEETBUS_PRUNE_EVERY_S", env, DEFAULT_PRUNE_EVERY_S, float),
    }


def _positive(name: str, env: Mapping[str, str], default: float, kind: type[float] | type[int]) -> float:
    value = env.get(name)
    if not value:
        return default
    try:
        number = kind(value)
    except ValueError:
        number = 0
    if number <= 0:
        raise ValueError(f"{name} must be a positive {'whole ' if kind is int else ''}number, not {value!r}")
    return number


def _rate(name: str, env: Mapping[str, str], default: str) -> str:
    """A rate such as ``5 per 5 minutes`` or ``20/hour`` (the ``limits`` library's notation)."""
    from limits import parse

    value = env.get(name) or default
    try:
        parse(value)
    except ValueError:
        raise ValueError(
            f"{name} must be a rate such as '5 per 5 minutes' or '20/hour', not {value!r}"
        ) from None
    return value


def _shards(value: str | None) -> int:
    if not value:
        return DEFAULT_INGEST_SHARDS
    try:
        shards = int(value)
    except ValueError:
        shards = 0
    if not 1 <= shards <= MAX_INGEST_SHARDS:
        raise ValueError(
            f"FLEETBUS_INGEST_SHARDS must be a whole number from 1 to {MAX_INGEST_SHARDS}, not {value!r}"
        )
    return shards
