"""schemathesis, an outside peer, against `fleetbus api` and the OpenAPI document it serves, with a
token of each role: every answer must be one the document promises.

The five checks: no server error; every status and content type one the document lists for the
operation; every body valid against the document's schema for it; every request the document
says is invalid refused (a 4xx). The data: a fixed seed, a bounded number of examples per
operation and phase, the boundary values schemathesis derives from the document (its coverage
phase) and the edge values of every numeric parameter (``schemathesis_hooks.py``).

Each role is run against the operations it may call (``x-roles``): the others answer 403 before
they look at the request, which the table of ``tests/api/test_roles.py`` checks for every role
and operation. The public operations (login, health, the CA) run once, with the guest's token.
The roles run at once; the admin on an API process and store of its own, so that it cannot remove
or demote another role's user while that one is being tested.
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from tests.peers import PEERS, ROOT, peer_command
from tests.peers.served_api import ROLES, ServedApi, served_api
from tests.support import Bus

CHECKS = (
    "not_a_server_error",
    "status_code_conformance",
    "content_type_conformance",
    "response_schema_conformance",
    "negative_data_rejection",
)
PHASES = "examples,coverage,fuzzing"
SEED = 20261127
MAX_EXAMPLES = 4
CONFIG = PEERS / "schemathesis.toml"
#: Who runs the operations no role check guards.
PUBLIC_RUNNER = "guest"


def schemathesis_command(base: str, token: str, report: Path, operation_ids: list[str]) -> list[str]:
    """The command, run from the checkout's root as the docs show it, for these operations."""
    return [
        str(peer_command("schemathesis")),
        "--config-file",
        str(CONFIG.relative_to(ROOT)),
        "run",
        f"{base}/openapi.json",
        "--header",
        f"Authorization: Bearer {token}",
        "--checks",
        ",".join(CHECKS),
        "--phases",
        PHASES,
        "--seed",
        str(SEED),
        "--max-examples",
        str(MAX_EXAMPLES),
        "--generation-database",
        "none",
        *(option for operation in operation_ids for option in ("--include-operation-id", operation)),
        "--report",
        "json",
        "--report-json-path",
        str(report),
        "--no-color",
    ]


def operations_for(document: dict[str, Any], role: str) -> list[str]:
    return [
        operation["operationId"]
        for operations in document["paths"].values()
        for operation in operations.values()
        if role in operation.get("x-roles", [PUBLIC_RUNNER])
    ]


def run_as(api: ServedApi, role: str, folder: Path) -> tuple[dict[str, Any], str]:
    """schemathesis's JSON report and its output."""
    report = folder / f"{role}.json"
    command = schemathesis_command(api.base, api.tokens[role], report, operations_for(api.document(), role))
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert report.exists(), f"schemathesis as {role} wrote no report:\n{done.stdout}\n{done.stderr}"
    return json.loads(report.read_text()), done.stdout + done.stderr


def test_every_role_gets_only_answers_the_openapi_document_promises(bus: Bus, tmp_path: Path) -> None:
    others = [role for role in ROLES if role != "admin"]
    admins_store = {"FLEETBUS_DATA_DIR": str(tmp_path / "admin-api")}
    with (
        served_api(bus, ["admin"], prefix="peer1", **admins_store) as admin,
        served_api(bus, others, prefix="peer2") as api,
        ThreadPoolExecutor(len(ROLES)) as pool,
    ):
        served = {role: admin if role == "admin" else api for role in ROLES}
        runs = {role: pool.submit(run_as, served[role], role, tmp_path) for role in ROLES}
        results = {role: run.result() for role, run in runs.items()}
    failed = []
    for role, (report, output) in results.items():
        operations, cases = report["operations"], report["test_cases"]
        print(
            f"schemathesis as {role}: {operations['tested']} operations, {cases['generated']} examples, "
            f"{cases['with_failures']} failing ({report['running_time']:.0f} s)"
        )
        if report["exit_code"] != 0 or report["failures"] or report["errors"] or not operations["tested"]:
            failed.append(f"--- as {role}:\n{output}")
    assert not failed, "\n".join(failed)


def test_the_docs_show_the_command_the_suite_runs() -> None:
    """The guide's command, and the HTTP API reference's, run what this test runs."""
    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "scripts" / "docs_hooks.py")
    assert spec is not None and spec.loader is not None
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    pages = {"guide": (ROOT / "docs/guides/service-layer.md").read_text(), "reference": hooks.http_api_page()}
    for page, text in pages.items():
        assert f"schemathesis --config-file {CONFIG.relative_to(ROOT)} run" in text, page
        assert f"--checks {','.join(CHECKS)} " in text, page
        assert f"--phases {PHASES} --seed {SEED} --max-examples {MAX_EXAMPLES}" in text, page
