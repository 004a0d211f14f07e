"""compose.yaml, read (no Docker engine runs here): who holds which credential.

MongoDB has authentication, with a root user from the environment that no fleetbus process
uses, and an application user that may read and write fleetbus's database only; the worker holds
the service accounts alone, which the one-shot `setup` service makes as the administrator.
"""

from __future__ import annotations

import importlib.util
import os
import re
import stat
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import yaml

from fleetbus.broker.accounts import SERVICE_USER
from fleetbus_dev.rabbitmq import TESTED_RELEASE

ROOT = Path(__file__).resolve().parent.parent
SERVICES: dict[str, Any] = yaml.safe_load((ROOT / "compose.yaml").read_text())["services"]


def required_variable(value: str) -> str:
    """The variable a ``${NAME:?message}`` reference requires (compose refuses to start without it)."""
    match = re.fullmatch(r"\$\{(\w+):\?[^}]*\}", value)
    assert match, f"{value!r} does not require a variable"
    return match[1]


def test_mongodb_has_a_root_user_from_the_environment_and_runs_the_user_script() -> None:
    mongo = SERVICES["mongo"]
    environment = mongo["environment"]
    assert environment["MONGO_INITDB_ROOT_USERNAME"] == "root"
    assert required_variable(environment["MONGO_INITDB_ROOT_PASSWORD"]) == "FLEETBUS_MONGODB_ROOT_PASSWORD"
    assert required_variable(environment["FLEETBUS_MONGODB_PASSWORD"]) == "FLEETBUS_MONGODB_PASSWORD"
    mounts = {volume.split(":")[1]: volume.split(":")[0] for volume in mongo["volumes"]}
    assert (ROOT / mounts["/docker-entrypoint-initdb.d"] / "fleetbus-user.js").exists()


def test_the_application_user_may_read_and_write_fleetbus_database_only() -> None:
    script = (ROOT / "mongo-init" / "fleetbus-user.js").read_text()
    assert 'db.getSiblingDB("fleetbus").createUser(' in script
    assert re.search(r'user:\s*"fleetbus"', script)
    assert "process.env.FLEETBUS_MONGODB_PASSWORD" in script
    roles = re.findall(r"\{\s*role:\s*\"(\w+)\",\s*db:\s*\"(\w+)\"\s*\}", script)
    assert roles == [("readWrite", "fleetbus")], "one role, on fleetbus's database"


def test_every_fleetbus_process_logs_in_to_mongodb_as_the_application_user() -> None:
    users = {}
    for name, service in SERVICES.items():
        url = (service.get("environment") or {}).get("FLEETBUS_MONGODB_URL")
        if url:
            parts = urlsplit(url.replace("${FLEETBUS_MONGODB_PASSWORD:?set FLEETBUS_MONGODB_PASSWORD}", "pw"))
            users[name] = (parts.username, parts.path)
    assert users == {"worker": ("fleetbus", "/fleetbus"), "api": ("fleetbus", "/fleetbus")}


def test_the_worker_holds_the_service_accounts_alone() -> None:
    worker, setup = SERVICES["worker"], SERVICES["setup"]
    assert "FLEETBUS_BROKER_PASSWORD" not in yaml.safe_dump(worker), "the administrator's password"
    assert "FLEETBUS_AMQP_URL" not in worker["environment"]
    service_url = urlsplit(worker["environment"]["FLEETBUS_SERVICE_URL"])
    assert service_url.username == SERVICE_USER and service_url.password is None
    assert "service-credentials:/data/accounts:ro" in worker["volumes"]
    assert worker["depends_on"]["setup"] == {"condition": "service_completed_successfully"}
    assert setup["command"] == ["fleetbus", "setup"] and "FLEETBUS_AMQP_URL" in setup["environment"]
    assert "service-credentials:/data/accounts" in setup["volumes"]


def test_the_api_hands_out_no_broker_password_over_plain_http_unless_the_operator_says_so() -> None:
    api = SERVICES["api"]
    assert "--tls" not in api["command"]
    assert api["environment"]["FLEETBUS_API_INSECURE_HTTP"] == "${FLEETBUS_API_INSECURE_HTTP:-false}"
    assert api["ports"] == ["127.0.0.1:8000:8000"]


def test_a_site_is_its_own_profile_and_its_worker_holds_the_service_accounts_alone() -> None:
    site = {name: service for name, service in SERVICES.items() if "site" in service.get("profiles", [])}
    assert set(site) == {"site-certs", "site-rabbitmq", "site-up", "site-worker", "site-apply"}
    central = {name: s for name, s in SERVICES.items() if name not in site and name not in CLUSTER_NODES}
    assert not any(service.get("profiles") for service in central.values())
    worker = site["site-worker"]
    assert "FLEETBUS_BROKER_PASSWORD" not in yaml.safe_dump(worker)
    assert "FLEETBUS_MONGODB_URL" not in worker["environment"], "a site stores in SQLite"
    service_url = urlsplit(worker["environment"]["FLEETBUS_SERVICE_URL"])
    assert service_url.username == SERVICE_USER and service_url.password is None
    assert site["site-up"]["command"][:3] == ["fleetbus", "site", "up"]
    assert "--central" not in site["site-up"]["command"], "the URL holds a password: never in argv"
    assert required_variable(site["site-up"]["environment"]["FLEETBUS_CENTRAL_URL"]) == "FLEETBUS_CENTRAL_URL"
    plugins = (ROOT / "compose" / "site-enabled-plugins").read_text()
    assert "rabbitmq_shovel," in plugins and "rabbitmq_shovel_management" in plugins


#: The cluster profile's nodes beside central's `rabbitmq` (docs/operations/cluster.md).
CLUSTER_NODES = ("rabbitmq-2", "rabbitmq-3")
CENTRAL = {"certs", "rabbitmq", "mongo", "setup", "worker", "api"}
SITE = {"site-certs", "site-rabbitmq", "site-up", "site-worker", "site-apply"}


def started(*profiles: str, named: tuple[str, ...] = ()) -> set[str]:
    """What ``docker compose --profile P... up -d [NAMED...]`` starts, by the Compose specification's
    rule (compose-go's ``HasProfile``): a service without profiles always, one with profiles when one
    is active; with service names, those and what they depend on, transitively."""
    if not named:
        return {
            name
            for name, service in SERVICES.items()
            if not service.get("profiles") or set(service["profiles"]) & set(profiles)
        }
    wanted, todo = set(), list(named)
    while todo:
        name = todo.pop()
        if name not in wanted:
            wanted.add(name)
            todo += list(SERVICES[name].get("depends_on") or {})
    return wanted


def test_the_central_profile_starts_central_alone_as_plain_up_does() -> None:
    assert started() == started("central") == CENTRAL, "no profile is still central, as before sites"
    assert started("central", "cluster") == CENTRAL | set(CLUSTER_NODES)
    assert all(started(named=(name,)) <= CENTRAL for name in CENTRAL), "central depends on nothing else"
    assert "FLEETBUS_MONGODB_URL" in SERVICES["worker"]["environment"], "central stores in MongoDB"
    header = (ROOT / "compose.yaml").read_text().split("\nname:")[0]
    assert "docker compose --profile central up -d" in header


def test_a_site_is_started_by_its_services_names_without_central() -> None:
    """Central's services start with every profile (they have none), on the site broker's ports:
    the documented command names the site's services, which depend on nothing of central's."""
    assert started("site") == CENTRAL | SITE
    ports = {name: set(SERVICES[name].get("ports", [])) for name in ("rabbitmq", "site-rabbitmq")}
    assert ports["rabbitmq"] & ports["site-rabbitmq"], "why `--profile site` alone would not do"
    command = "docker compose --profile site up -d site-rabbitmq site-up site-worker site-apply"
    for document in ("compose.yaml", "docs/operations/compose.md", "docs/guides/sites.md"):
        assert command in (ROOT / document).read_text(), document
    assert started("site", named=tuple(command.split()[6:])) == SITE


def test_every_broker_runs_the_release_the_suite_tests() -> None:
    images = {name: SERVICES[name]["image"] for name in BROKERS}
    assert images == dict.fromkeys(BROKERS, f"rabbitmq:{TESTED_RELEASE}-management")


def test_the_cluster_profile_adds_two_nodes_of_the_same_release_sharing_one_cookie() -> None:
    nodes = {name: SERVICES[name] for name in ("rabbitmq", "rabbitmq-2", "rabbitmq-3")}
    assert len({service["image"] for service in nodes.values()}) == 1
    assert "profiles" not in nodes["rabbitmq"], "node 1 is the single broker too"
    assert all(nodes[name]["profiles"] == ["cluster"] for name in ("rabbitmq-2", "rabbitmq-3"))
    # the cookie is no argument and has no default: `certs` writes one into each node's data volume
    text = (ROOT / "compose.yaml").read_text()
    assert "setcookie" not in text and "ERLANG_COOKIE" not in text
    certs = SERVICES["certs"]
    homes = {volume.split(":")[0]: volume.split(":")[1] for volume in certs["volumes"]}
    data = {name: service["volumes"][0].split(":")[0] for name, service in nodes.items()}
    assert all(service["volumes"][0].endswith(":/var/lib/rabbitmq") for service in nodes.values())
    assert f"erlang_cookie.py {' '.join(homes[data[name]] for name in nodes)}" in certs["command"][-1]
    for name in ("setup", "worker", "api"):
        environment = SERVICES[name]["environment"]
        url = environment.get("FLEETBUS_AMQP_URL") or environment["FLEETBUS_SERVICE_URL"]
        assert "@${FLEETBUS_BROKER_HOSTS:-rabbitmq:5671}/" in url, f"{name} lists every node"
        assert environment["FLEETBUS_CLUSTER"] == "${FLEETBUS_CLUSTER:-false}"


def test_the_nodes_cookie_is_made_once_kept_and_shared_owner_only(tmp_path: Path) -> None:
    """compose/erlang_cookie.py, as `certs` runs it, on three node folders: a random cookie in all,
    0400 and RabbitMQ's; run again, the same; a new node's folder gets the cookie the others have."""
    spec = importlib.util.spec_from_file_location("erlang_cookie", ROOT / "compose" / "erlang_cookie.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    homes = [tmp_path / name for name in ("rabbitmq", "rabbitmq-2", "rabbitmq-3")]
    module.share_cookie(homes[:2], uid=os.getuid())
    first = (homes[0] / ".erlang.cookie").read_text()
    assert len(first) == 64 and (homes[1] / ".erlang.cookie").read_text() == first
    said = module.share_cookie(homes, uid=os.getuid())
    assert [(home / ".erlang.cookie").read_text() for home in homes] == [first] * 3
    assert first not in said, "the cookie is never printed"
    assert {stat.S_IMODE((home / ".erlang.cookie").stat().st_mode) for home in homes} == {0o400}


#: The brokers and who makes their certificates; the fleetbus services of each side.
BROKERS = {"rabbitmq": "certs", "rabbitmq-2": "certs", "rabbitmq-3": "certs", "site-rabbitmq": "site-certs"}
CLIENTS = {"setup": "rabbitmq", "worker": "rabbitmq", "api": "rabbitmq"} | {
    name: "site-rabbitmq" for name in ("site-up", "site-worker", "site-apply")
}
TLS_CONFIG = [
    line.strip()
    for line in yaml.safe_load((ROOT / "compose.yaml").read_text())["configs"]["rabbitmq-tls"][
        "content"
    ].splitlines()
]


def _mounts(service: dict[str, Any]) -> dict[str, str]:
    """Target to source of a service's volumes (short and long syntax)."""
    found = {}
    for volume in service.get("volumes", []):
        if isinstance(volume, dict):
            found[volume["target"]] = volume["source"]
        else:
            source, target = volume.split(":")[:2]
            found[target] = source
    return found


def test_every_broker_listens_on_amqps_and_https_with_the_certificate_its_certs_service_made() -> None:
    assert "listeners.ssl.default = 5671" in TLS_CONFIG and "management.ssl.port = 15671" in TLS_CONFIG
    assert "ssl_options.keyfile = /etc/fleetbus/tls/server.key" in TLS_CONFIG
    for broker, maker in BROKERS.items():
        service = SERVICES[broker]
        assert {c["source"] for c in service["configs"]} >= {"rabbitmq-tls"}, broker
        volume = _mounts(service)["/etc/fleetbus/tls"]
        assert _mounts(SERVICES[maker])["/tls"] == volume, f"{broker} serves what {maker} made"
    for maker in set(BROKERS.values()):
        command = " ".join(SERVICES[maker]["command"])
        assert "fleetbus certs make --dir /tls" in command and SERVICES[maker]["user"] == "0"
        # the RabbitMQ image runs as uid 999: the key is its alone
        assert "chown 999:999 /tls/server.key && chmod 0600 /tls/server.key" in command
    assert SERVICES["rabbitmq"]["depends_on"]["certs"] == {"condition": "service_completed_successfully"}
    assert SERVICES["site-rabbitmq"]["depends_on"]["site-certs"] == {
        "condition": "service_completed_successfully"
    }


def test_every_fleetbus_service_reaches_its_broker_over_verified_tls() -> None:
    for name, broker in CLIENTS.items():
        environment = SERVICES[name]["environment"]
        url = environment.get("FLEETBUS_AMQP_URL") or environment["FLEETBUS_SERVICE_URL"]
        assert url.startswith("amqps://") and url.endswith("/?cacertfile=/etc/fleetbus/tls/ca.pem"), name
        assert f"@{broker}:5671/" in url or "${FLEETBUS_BROKER_HOSTS:-rabbitmq:5671}" in url, name
        management = environment.get("FLEETBUS_MANAGEMENT_URL", f"https://{broker}:15671/")
        assert management == f"https://{broker}:15671/", name
        if "${FLEETBUS_BROKER_HOSTS" in url:  # derived from every node's address: it fails over
            assert "FLEETBUS_MANAGEMENT_URL" not in environment, f"{name}: the management API on one node"
        assert environment["FLEETBUS_TLS_CA"] == "/etc/fleetbus/tls/ca.pem", name
        assert (
            _mounts(SERVICES[name])["/etc/fleetbus/tls"] == _mounts(SERVICES[broker])["/etc/fleetbus/tls"]
        ), name


def test_a_site_verifies_central_with_centrals_ca_which_must_be_there() -> None:
    """The shovels run in the site's broker and `site up` checks the URL first: both read central's
    CA at the path FLEETBUS_CENTRAL_URL names; a missing file stops Compose rather than becoming an
    empty folder."""
    for name in ("site-rabbitmq", "site-up", "site-apply"):
        [ca] = [v for v in SERVICES[name]["volumes"] if isinstance(v, dict)]
        assert ca["source"] == "./compose/central-ca.pem" and ca["target"] == "/etc/fleetbus/central-ca.pem"
        assert ca["read_only"] is True and ca["bind"] == {"create_host_path": False}
    assert "cacertfile=/etc/fleetbus/central-ca.pem" in (ROOT / "compose.yaml").read_text()
