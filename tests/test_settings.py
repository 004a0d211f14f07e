"""The settings model: one field per variable, each described; the docs' table is generated from it."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from fleetbus.settings import Settings, load_settings, settings_table, variable, with_settings_table

ROOT = Path(__file__).resolve().parent.parent
SETTINGS_PAGE = ROOT / "docs" / "reference" / "settings.md"


def test_the_docs_settings_table_is_the_generated_one() -> None:
    text = SETTINGS_PAGE.read_text()
    assert with_settings_table(text) == text, (
        "docs/reference/settings.md's table is not the model's: "
        "`python -m fleetbus.settings --update docs/reference/settings.md`"
    )


def test_every_setting_is_described_and_in_the_table() -> None:
    table = settings_table()
    for name, field in Settings.model_fields.items():
        assert field.description, f"{variable(name)} has no description"
        assert f"| `{variable(name)}` |" in table


def test_every_variable_compose_reads_is_in_the_table() -> None:
    """compose.yaml's own variables (a host name, a password) are listed beside the settings."""
    table = settings_table()
    read = set(re.findall(r"\$\{(FLEETBUS_[A-Z0-9_]+)", (ROOT / "compose.yaml").read_text()))
    assert read, "compose.yaml reads no FLEETBUS_ variable: the pattern is wrong"
    assert sorted(name for name in read if f"| `{name}` |" not in table) == []


def test_a_given_environment_is_the_only_one_read(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FLEETBUS_AMQP_URL", "amqp://elsewhere/")
    monkeypatch.setenv("FLEETBUS_INGEST_SHARDS", "7")
    assert load_settings().amqp_url == "amqp://elsewhere/"
    given = load_settings({"FLEETBUS_INGEST_SHARDS": "3", "FLEETBUS_RECORDER_INCLUDE": "a.#, b.*  c"})
    assert given.amqp_url is None
    assert given.ingest_shards == 3
    assert given.recorder_include == ("a.#", "b.*", "c")


def test_empty_variables_are_unset_and_lists_split_on_commas_and_spaces(tmp_path: Path) -> None:
    settings = load_settings(
        {"FLEETBUS_AMQP_URL": "", "FLEETBUS_INBOX_MAX": " 5,1MB", "FLEETBUS_DATA_DIR": str(tmp_path / "d")}
    )
    assert settings.amqp_url is None
    assert settings.inbox_max == ("5", "1MB")
    assert settings.data_dir == tmp_path / "d"
    assert load_settings({}).data_dir.is_absolute()


@pytest.mark.parametrize(
    ("variable_name", "value", "says"),
    [
        ("FLEETBUS_INGEST_SHARDS", "65", "a whole number from 1 to 64, not '65'"),
        ("FLEETBUS_BROKER_WAIT_S", "-1", "must be a positive number, not '-1'"),
        ("FLEETBUS_API_HASH_THREADS", "1.5", "must be a positive whole number, not '1.5'"),
        ("FLEETBUS_API_ACCOUNT_FAILURES", "often", "must be a rate such as"),
        ("FLEETBUS_MAX_MESSAGE_BYTES", "lots", "valid integer"),
        ("FLEETBUS_LATE_AFTER_S", "soon", "valid number"),
    ],
)
def test_a_value_that_does_not_parse_stops_at_start_naming_its_variable(
    variable_name: str, value: str, says: str
) -> None:
    with pytest.raises(ValueError, match=variable_name) as refused:
        load_settings({variable_name: value})
    assert says in str(refused.value)


def test_settings_are_frozen_and_updated_by_name() -> None:
    settings = load_settings({})
    with pytest.raises(ValueError, match="frozen"):
        settings.ingest_shards = 2  # type: ignore[misc]
    assert settings.updated(ingest_shards=2).ingest_shards == 2
    with pytest.raises(TypeError, match="no such setting: shards"):
        settings.updated(shards=2)


def test_secrets_are_not_shown() -> None:
    settings = load_settings({"FLEETBUS_API_SECRET": "s3cret-value", "FLEETBUS_BROKER_PASSWORD": "pw-value"})
    assert "s3cret-value" not in repr(settings) and "pw-value" not in repr(settings)
    assert settings.api_secret is not None and settings.api_secret.get_secret_value() == "s3cret-value"
