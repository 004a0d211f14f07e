"""What a robot installs: the wheel's base install (schemas and the robot client) pulls pika,
tinydb, pydantic and pyyaml and nothing else, installs under the ``fleetbus`` namespace only, and
publishes through the robot client to the real broker, where a worker stores what it sent."""

from __future__ import annotations

import json
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import pytest

from fleetbus.schemas.routing import RobotKind
from tests.factories import hazard
from tests.support import PROJECT_ROOT, Bus, wait_for

ROOT = Path(__file__).resolve().parent.parent

#: What the base install may bring: the four named dependencies and what they need themselves.
BASE = {"pika", "tinydb", "pydantic", "pyyaml"}
THEIRS = {"pydantic-core", "annotated-types", "typing-extensions", "typing-inspection"}

ROBOT_PROGRAM = """
import json, sys
from fleetbus.publishers.client import RobotClient
with RobotClient(sys.stdin.readline().strip(), state_dir=sys.argv[1]) as robot:  # the URL: stdin
    event = robot.publish("hazard", json.loads(sys.argv[2]))
print(json.dumps({"message_id": str(event.message_id), "modules": sorted(sys.modules)}))
"""


def pip_for(python: Path) -> list[str]:
    """pip working on the environment of ``python``."""
    return [sys.executable, "-m", "pip", "--python", str(python)]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out), str(ROOT)],
        check=True,
        capture_output=True,
        timeout=300,
    )
    [built] = out.glob("fleetbus-*.whl")
    return built


@pytest.fixture(scope="module")
def base_install(wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A clean venv with the wheel and its base dependencies only; its python. (Installed by this
    Python's pip, ``--python``: a pip of the venv's own would take seconds to install, and nothing
    a robot needs.)"""
    where = tmp_path_factory.mktemp("robot-venv")
    venv.create(where)
    python = where / "bin" / "python"
    subprocess.run(
        [*pip_for(python), "install", "--disable-pip-version-check", "-q", str(wheel)],
        check=True,
        capture_output=True,
        timeout=600,
    )
    return python


def test_everything_installs_under_the_fleetbus_namespace_without_the_development_tooling(
    wheel: Path,
) -> None:
    names = zipfile.ZipFile(wheel).namelist()
    top = {name.split("/")[0] for name in names if not name.split("/")[0].endswith(".dist-info")}
    assert top == {"fleetbus"}, "the development tooling (fleetbus_dev) is a distribution of its own"
    for package in ("schemas", "publishers", "broker", "workers", "api", "cli"):
        assert f"fleetbus/{package}/__init__.py" in names
    assert not [name for name in names if name.startswith("fleetbus/dev/")]
    assert not [name for name in names if "commands/broker.py" in name or "commands/demo.py" in name]


def test_an_installed_fleetbus_run_from_the_checkout_is_the_installed_one(base_install: Path) -> None:
    """No folder of the checkout shadows the installed package: run from the checkout's root (the
    current folder first on the path), ``fleetbus`` and its subpackages are the installed ones."""
    program = "import fleetbus, fleetbus.publishers.client, fleetbus.schemas; print(fleetbus.__file__)"
    ran = subprocess.run(
        [str(base_install), "-c", program], cwd=PROJECT_ROOT, capture_output=True, text=True, timeout=60
    )
    assert ran.returncode == 0, ran.stderr
    assert Path(ran.stdout.strip()).is_relative_to(base_install.parent.parent), ran.stdout


def test_the_base_install_pulls_only_what_a_robot_needs(base_install: Path) -> None:
    listed = subprocess.run(
        [*pip_for(base_install), "list", "--format=json", "--disable-pip-version-check"],
        check=True,
        capture_output=True,
        text=True,
    )
    installed = {entry["name"].lower().replace("_", "-") for entry in json.loads(listed.stdout)}
    installed -= {"pip", "setuptools", "wheel", "fleetbus"}
    assert BASE <= installed
    assert installed <= BASE | THEIRS, f"more than a robot needs: {sorted(installed - BASE - THEIRS)}"


def test_a_robot_publishes_through_the_base_install(base_install: Path, bus: Bus, tmp_path: Path) -> None:
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    with bus.worker():
        ran = subprocess.run(
            [
                str(base_install),
                "-c",
                ROBOT_PROGRAM,
                str(tmp_path / "robot"),
                json.dumps(hazard()),
            ],
            input=account.amqp_url + "\n",  # a password is never an argument
            capture_output=True,
            text=True,
            timeout=120,
            cwd=tmp_path,  # not the repository: only the installed package is importable
        )
        assert ran.returncode == 0, ran.stderr
        result = json.loads(ran.stdout)
        wait_for(lambda: bus.count(robot_id="explorer1") == 1, timeout=60, what="the hazard stored")
    [stored] = bus.find()
    assert str(stored.message_id) == result["message_id"] and stored.type == "hazard"
    server_side = {
        "aio_pika",
        "pymongo",
        "fastapi",
        "typer",
        "fleetbus.workers",
        "fleetbus.api",
        "fleetbus.cli",
    }
    assert not server_side & set(result["modules"]), "the robot client imported server code"


def test_the_console_ships_its_templates_and_every_file_it_serves(wheel: Path) -> None:
    names = set(zipfile.ZipFile(wheel).namelist())
    console = PROJECT_ROOT / "api" / "console"
    served = [
        path.relative_to(PROJECT_ROOT)
        for path in console.rglob("*")
        if path.is_file() and "__pycache__" not in path.parts and path.suffix != ".py"
    ]
    assert served, "no console files found"
    for path in served:
        assert f"fleetbus/{path.as_posix()}" in names, f"{path} is not in the wheel"
