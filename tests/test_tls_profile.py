"""The TLS profile (fleetbus.broker.tls_profile) in each form it is written: the private node's
configuration, uvicorn's context, and the copies in compose.yaml and docs/operations/tls.md, which
must say exactly what the code says. (sslyze checks what the listeners really accept:
tests/peers/test_tls_listeners.py, tests/cluster/, tests/sites/.)"""

from __future__ import annotations

import re
import ssl
from pathlib import Path

import yaml

from fleetbus.broker import tls_profile
from fleetbus.broker.tls_profile import AMQPS, MANAGEMENT, erlang_terms, rabbitmq_conf
from fleetbus_dev.local_node import LocalNode
from tests.peers.tls_scan import weakness

ROOT = Path(__file__).resolve().parent.parent
GUIDE = ROOT / "docs" / "operations" / "tls.md"
#: A line of rabbitmq.conf that sets part of the profile, for either listener.
PROFILE_LINE = re.compile(r"^(ssl_options|management\.ssl)\.(versions|ciphers|honor_cipher_order)\b")


def _profile_lines(text: str) -> list[str]:
    return [line.strip() for line in text.splitlines() if PROFILE_LINE.match(line.strip())]


def _blocks(language: str) -> list[str]:
    return re.findall(rf"^```{language}\n(.*?)^```", GUIDE.read_text(), flags=re.M | re.S)


def _squeezed(text: str) -> str:
    return re.sub(r"\s+", "", text)


def test_the_profile_is_tls_1_2_and_1_3_with_forward_secret_aead_suites_only() -> None:
    assert tls_profile.VERSIONS == ("tlsv1.3", "tlsv1.2")
    for suite in tls_profile.TLS12_SUITES:
        assert suite.startswith("ECDHE-") and ("-GCM-" in suite or suite.endswith("-CHACHA20-POLY1305"))
    assert all(weakness(suite, "TLS 1.3") is None for suite in tls_profile.TLS13_SUITES)
    assert tls_profile.ciphers()[:3] == tls_profile.TLS13_SUITES  # one list for both versions
    assert rabbitmq_conf(MANAGEMENT).splitlines()[:2] == [
        "management.ssl.versions.1 = tlsv1.3",
        "management.ssl.versions.2 = tlsv1.2",
    ]
    assert "{versions, ['tlsv1.3', 'tlsv1.2']}" in erlang_terms()


def test_the_api_context_offers_the_profile_and_nothing_else() -> None:
    context = tls_profile.apply(ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER))
    assert context.minimum_version is ssl.TLSVersion.TLSv1_2
    assert not context.options & ssl.OP_CIPHER_SERVER_PREFERENCE
    offered = {suite["name"] for suite in context.get_ciphers()}
    assert offered == set(tls_profile.TLS13_SUITES) | set(tls_profile.TLS12_SUITES)


def test_the_private_node_writes_the_profile_for_both_listeners(tmp_path: Path) -> None:
    """In rabbitmq.conf for the management API; in advanced.config for AMQPS, whose ``ssl_options``
    RabbitMQ then takes from there alone (the revocation list can be given only there)."""
    node = LocalNode(tmp_path / "broker")
    node._write_config()
    conf = (node.base_dir / "rabbitmq.conf").read_text()
    assert _profile_lines(conf) == rabbitmq_conf(MANAGEMENT).splitlines()
    advanced = (node.base_dir / "advanced.config").read_text()
    assert all(term in advanced for term in erlang_terms())


def test_compose_brokers_serve_the_profile() -> None:
    configs = yaml.safe_load((ROOT / "compose.yaml").read_text())["configs"]
    tls = configs["rabbitmq-tls"]["content"]
    assert _profile_lines(tls) == (rabbitmq_conf(AMQPS) + rabbitmq_conf(MANAGEMENT)).splitlines()
    others = "".join(config["content"] for name, config in configs.items() if name != "rabbitmq-tls")
    assert not _profile_lines(others)


def test_the_guide_gives_a_broker_you_run_the_profile() -> None:
    [conf] = [block for block in _blocks("ini") if "listeners.ssl.default" in block]
    assert _profile_lines(conf) == (rabbitmq_conf(AMQPS) + rabbitmq_conf(MANAGEMENT)).splitlines()
    [advanced] = [block for block in _blocks("erlang") if "ssl_options" in block]
    for term in erlang_terms():
        assert _squeezed(advanced).count(_squeezed(term)) == 1, term
    assert _squeezed(advanced).count("{versions,") == 1 and _squeezed(advanced).count("{ciphers,") == 1
