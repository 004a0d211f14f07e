"""sslyze, a TLS scanner nobody on the project wrote, run against fleetbus's TLS listeners: which
protocol versions and cipher suites each accepts, and whether its certificate verifies against
the project's CA for each name robots are told to use.

One scan runs every listener given at once (sslyze connects to them concurrently): the protocol
scans against each listener's address, and, in a second sslyze beside it, the certificate checks
for each further name (``localhost:PORT{127.0.0.1}``: that name sent and verified, that address
dialled). sslyze's own JSON output (``--json_out``) is what is read.
"""

from __future__ import annotations

import json
import re
import subprocess
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tests.peers import peer_command

#: sslyze's JSON keys of the protocol scans, and the protocol each one tries.
REFUSED = {
    "ssl_2_0_cipher_suites": "SSL 2.0",
    "ssl_3_0_cipher_suites": "SSL 3.0",
    "tls_1_0_cipher_suites": "TLS 1.0",
    "tls_1_1_cipher_suites": "TLS 1.1",
}
REQUIRED = {"tls_1_2_cipher_suites": "TLS 1.2", "tls_1_3_cipher_suites": "TLS 1.3"}
PROTOCOL_SCANS = ("--sslv2", "--sslv3", "--tlsv1", "--tlsv1_1", "--tlsv1_2", "--tlsv1_3")
#: sslyze's name of the trust store ``--certinfo_ca_file`` gives it.
SUPPLIED_CA = "Supplied CA file"
#: The names the docs give robots for a node of this machine: its URL's address, and the name a
#: shovel checks (docs/operations/tls.md); ``fleetbus certs make`` signs both, with any --host.
NODE_NAMES = ("127.0.0.1", "localhost")
SCAN_TIMEOUT = 120


@dataclass(frozen=True)
class Listener:
    """A TLS listener on this machine and the names its certificate must verify for."""

    label: str
    port: int
    ca: Path
    names: Sequence[str] = NODE_NAMES
    address: str = "127.0.0.1"


@dataclass
class Finding:
    """What sslyze found at one listener."""

    listener: Listener
    accepted: dict[str, list[str]] = field(default_factory=dict)
    """Protocol (``TLS 1.2``) to the IANA names of the suites accepted with it."""
    without_ephemeral_key: list[str] = field(default_factory=list)
    """Suites sslyze saw accepted with no ephemeral key exchanged (no forward secrecy)."""
    trust: dict[str, str | None] = field(default_factory=dict)
    """Name to the error of verifying the certificate against the CA for it (None: verified)."""

    def summary(self) -> str:
        """One line: the protocols accepted (and how many suites with each), those refused, and
        each name the certificate was checked for."""
        accepted = [f"{name} ({len(suites)} suites)" for name, suites in self.accepted.items() if suites]
        refused = [name for name, suites in self.accepted.items() if not suites]
        names = [f"{name} {'NOT ' if error else ''}verified" for name, error in self.trust.items()]
        return (
            f"{self.listener.label} :{self.listener.port}: accepts {', '.join(accepted) or 'nothing'}; "
            f"refuses {', '.join(refused) or 'nothing'}; certificate for {', '.join(names)}"
        )

    def problems(self) -> list[str]:
        """Everything in which the listener falls short of the TLS profile (none: it holds)."""
        found = [f"accepts {name}" for name in REFUSED.values() if self.accepted.get(name)]
        found += [f"refuses {name}" for name in REQUIRED.values() if not self.accepted.get(name)]
        for name, suites in self.accepted.items():
            found += [f"{name} {suite}: {why}" for suite in suites if (why := weakness(suite, name))]
        found += [f"{suite}: no ephemeral key exchanged" for suite in self.without_ephemeral_key]
        found += [
            f"certificate does not verify for {name!r} against {self.listener.ca}: {error}"
            for name, error in self.trust.items()
            if error is not None
        ]
        return found


def weakness(suite: str, protocol: str = "TLS 1.2") -> str | None:
    """Why a suite (IANA name) accepted with ``protocol`` is outside the profile: not forward-secret
    (no ECDHE or DHE key exchange; TLS 1.3's is always ephemeral), or its cipher neither AES-GCM
    nor ChaCha20-Poly1305 (CBC, CCM...)."""
    reasons = []
    if protocol != "TLS 1.3" and not re.match(r"TLS_(ECDHE|DHE)_", suite):
        reasons.append("not forward-secret")
    if "_GCM_" not in suite and "_CHACHA20_POLY1305_" not in suite:
        reasons.append("neither AES-GCM nor ChaCha20-Poly1305")
    return ", ".join(reasons) or None


def _sslyze(targets: Iterable[str], ca: Path, out: Path, scans: Sequence[str]) -> subprocess.Popen[bytes]:
    command = [
        str(peer_command("sslyze")),
        "--quiet",
        "--mozilla_config",
        "disable",
        "--json_out",
        str(out),
        "--certinfo",
        "--certinfo_ca_file",
        str(ca),
        *scans,
        *targets,
    ]
    return subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def _results(process: subprocess.Popen[bytes], out: Path) -> list[dict[str, Any]]:
    _, stderr = process.communicate(timeout=SCAN_TIMEOUT)
    assert process.returncode == 0, f"sslyze failed ({process.returncode}): {stderr.decode()[-2000:]}"
    report = json.loads(out.read_text())
    assert not report["invalid_server_strings"], report["invalid_server_strings"]
    results: list[dict[str, Any]] = report["server_scan_results"]
    for result in results:
        location = f"{result['server_location']['hostname']}:{result['server_location']['port']}"
        assert result["scan_status"] == "COMPLETED", f"sslyze could not scan {location}: {result}"
    return results


def _trust_error(result: dict[str, Any]) -> str | None:
    """The error of verifying every certificate chain the listener served against the CA (None:
    each verified, for the name the scan sent)."""
    info = result["scan_result"]["certificate_info"]
    if info["status"] != "COMPLETED":
        return f"no certificate information: {info['error_reason']}"
    for deployment in info["result"]["certificate_deployments"]:
        [supplied] = [
            check
            for check in deployment["path_validation_results"]
            if check["trust_store"]["name"] == SUPPLIED_CA
        ]
        if supplied["verified_certificate_chain"] is None:
            return supplied["validation_error"] or "not verified"
    return None


def scan(listeners: Sequence[Listener], folder: Path) -> list[Finding]:
    """Scan every listener (all with one CA) with sslyze; print what each accepts; return the
    findings in the order of ``listeners``."""
    [ca] = {listener.ca for listener in listeners}
    started = time.monotonic()
    findings = [Finding(listener) for listener in listeners]
    by_target = {f"{f.listener.address}:{f.listener.port}": f for f in findings}
    named = {
        f"{name}:{finding.listener.port}{{{finding.listener.address}}}": (finding, name)
        for finding in findings
        for name in finding.listener.names
        if name != finding.listener.address
    }
    protocols = _sslyze(by_target, ca, folder / "sslyze-protocols.json", PROTOCOL_SCANS)
    names = _sslyze(named, ca, folder / "sslyze-names.json", ()) if named else None
    for result in _results(protocols, folder / "sslyze-protocols.json"):
        location = result["server_location"]
        finding = by_target[f"{location['ip_address']}:{location['port']}"]
        for key, protocol in {**REFUSED, **REQUIRED}.items():
            attempt = result["scan_result"][key]
            assert attempt["status"] == "COMPLETED", f"{finding.listener.label}: {key}: {attempt}"
            accepted = attempt["result"]["accepted_cipher_suites"]
            finding.accepted[protocol] = [each["cipher_suite"]["name"] for each in accepted]
            finding.without_ephemeral_key += [
                each["cipher_suite"]["name"] for each in accepted if each["ephemeral_key"] is None
            ]
        if finding.listener.address in finding.listener.names:
            finding.trust[finding.listener.address] = _trust_error(result)
    if names is not None:
        for result in _results(names, folder / "sslyze-names.json"):
            location = result["server_location"]
            finding, name = named[f"{location['hostname']}:{location['port']}{{{location['ip_address']}}}"]
            finding.trust[name] = _trust_error(result)
    print(f"sslyze scanned {len(listeners)} listeners in {time.monotonic() - started:.1f} s:")
    for finding in findings:
        print("  " + finding.summary())
    return findings


def assert_profile(findings: Sequence[Finding]) -> None:
    """Every listener holds the TLS profile (fleetbus.broker.tls_profile)."""
    problems = {f.listener.label: f.problems() for f in findings if f.problems()}
    assert not problems, f"listeners outside the TLS profile: {json.dumps(problems, indent=2)}"
    for finding in findings:
        assert set(finding.trust) == set(finding.listener.names), finding.trust
