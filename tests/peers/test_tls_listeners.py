"""sslyze against the private node's AMQPS and management HTTPS listeners and `fleetbus api --tls`:
TLS 1.2 and 1.3 only, forward-secret AEAD suites only, and a certificate that verifies against
the project's CA for the names robots are told to use. (The cluster's nodes are scanned in
``tests/cluster/``, a site's node in ``tests/sites/``, where those nodes already run.)"""

from __future__ import annotations

import shutil
from pathlib import Path
from urllib.parse import urlsplit

import pytest

from fleetbus.broker.certificates import TlsFiles, make_certificates
from fleetbus_dev.local_node import LocalNode
from tests.api.server import api_process
from tests.peers.tls_scan import NODE_NAMES, Finding, Listener, assert_profile, scan, weakness
from tests.run_tls import run_tls_files
from tests.support import Bus

#: A name given to `fleetbus certs make --host`, as docs/operations/tls.md does for the API.
API_HOST = "api.example"


def test_the_private_node_and_the_api_accept_only_the_tls_profile(
    bus: Bus, broker_node: LocalNode | None, tmp_path: Path
) -> None:
    if broker_node is None:
        pytest.skip("the suite's broker is not the private node: its listeners are not fleetbus's")
    run = run_tls_files()
    api_files = TlsFiles.in_folder(tmp_path / "api-tls")  # the API's certificate, signed by the run's CA
    api_files.ca.parent.mkdir()
    for made, kept in ((run.ca, api_files.ca), (run.ca_key, api_files.ca_key)):
        shutil.copy2(made, kept)
    make_certificates(api_files, [API_HOST])
    ports = broker_node.status().ports
    folder = str(api_files.ca.parent)
    with api_process(bus, None, ca=api_files.ca, FLEETBUS_TLS_DIR=folder) as (base, _):
        port = urlsplit(base).port
        assert port is not None
        findings = scan(
            [
                Listener("private node AMQPS", ports["amqps"], run.ca),
                Listener("private node management HTTPS", ports["management_tls"], run.ca),
                Listener("fleetbus api --tls", port, run.ca, names=(*NODE_NAMES, API_HOST)),
            ],
            tmp_path,
        )
    assert_profile(findings)


def test_the_scan_finds_what_the_profile_refuses(tmp_path: Path) -> None:
    """What the check of a finding counts against a listener (what Erlang's defaults served)."""
    assert weakness("TLS_ECDH_ECDSA_WITH_AES_256_GCM_SHA384") == "not forward-secret"
    assert weakness("TLS_ECDHE_ECDSA_WITH_AES_128_CBC_SHA256") == "neither AES-GCM nor ChaCha20-Poly1305"
    assert weakness("TLS_RSA_WITH_AES_128_CBC_SHA") == (
        "not forward-secret, neither AES-GCM nor ChaCha20-Poly1305"
    )
    assert weakness("TLS_ECDHE_RSA_WITH_CHACHA20_POLY1305_SHA256") is None
    assert weakness("TLS_AES_128_GCM_SHA256", "TLS 1.3") is None
    assert weakness("TLS_AES_128_CCM_SHA256", "TLS 1.3") == "neither AES-GCM nor ChaCha20-Poly1305"
    finding = Finding(Listener("old", 1, tmp_path / "ca.pem"))
    finding.accepted = {"TLS 1.1": ["TLS_ECDHE_ECDSA_WITH_AES_128_CBC_SHA"], "TLS 1.2": [], "TLS 1.3": []}
    finding.trust = {"127.0.0.1": None, "localhost": "no subjectAltName matches"}
    problems = finding.problems()
    assert "accepts TLS 1.1" in problems and "refuses TLS 1.2" in problems and "refuses TLS 1.3" in problems
    assert any("neither AES-GCM" in problem for problem in problems)
    assert any("'localhost'" in problem for problem in problems)
