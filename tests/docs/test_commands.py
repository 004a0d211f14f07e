"""Every command line README.md and docs/ show: run against the real broker as a reader runs it,
or, where the page says it cannot run here and why, checked by its parser.

How a page's command is recognised, run or marked is in tests/docs/pages.py and
tests/docs/sandbox.py, and for writers in docs/contributing.md ("Commands in the documentation").
"""

from __future__ import annotations

import shutil
import warnings
from collections.abc import Callable
from datetime import datetime, timezone
from pathlib import Path

import pytest

from fleetbus_dev.local_node import LocalNode
from tests.docs.checks import check_without_running, words
from tests.docs.pages import Page, documentation_pages, read_page
from tests.docs.sandbox import Sandbox
from tests.support import Bus

PAGES = [read_page(path) for path in documentation_pages()]
RUN_HERE = [page for page in PAGES if any(command.not_run is None for command in page.commands)]
#: Programs that talk to a RabbitMQ node of their own (Erlang distribution): run against a node the
#: tests may change (``killable_node``), with its environment.
NODE_TOOLS = ("rabbitmqctl", "rabbitmq-queues", "rabbitmq-plugins")


def ros_bags(folder: Path) -> None:
    """The bags the ROS guide imports, by the names it shows: a ROS 1 bag, a ROS 2 bag directory
    (MCAP storage) and its storage file under the name the guide gives it."""
    from tests.ros_bags import storage_file, write_bag

    recorded = int(datetime(2026, 3, 2, 9, 0, 1, tzinfo=timezone.utc).timestamp()) * 10**9  # as named
    write_bag(folder / "run-2026-03-02.bag", "ros1", count=6, start_ns=recorded)
    ros2 = folder / "rosbag2_2026_03_02"
    write_bag(ros2, "ros2-mcap", count=6, start_ns=recorded)
    shutil.copy(storage_file(ros2), ros2 / "rosbag2_0.mcap")


#: Files a page's commands read that the page cannot show (a binary bag), made by the test.
MADE_FILES: dict[str, Callable[[Path], None]] = {"docs/guides/ros.md": ros_bags}


def test_every_command_is_in_a_shell_block_and_every_mark_is_read() -> None:
    """A command outside a shell block, or a mark without its reason, would slip past the runs."""
    problems = [problem for page in PAGES for problem in page.problems]
    assert not problems, "\n".join(problems)
    assert sum(len(page.commands) for page in PAGES) > 100, "the pages' commands were found"


def test_every_command_not_run_here_passes_its_parser() -> None:
    """``fleetbus`` resolves the subcommand and reads every option; compose.yaml has the services and
    profiles named; a benchmark's parser reads its arguments. Nothing runs."""
    problems = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # runpy, running a benchmark module again
        for page in PAGES:
            for command in page.commands:
                if command.not_run is not None and (problem := check_without_running(command.text)):
                    problems.append(f"{command.where}: {problem}")
    assert not problems, "\n".join(problems)


@pytest.mark.timeout(900)  # a page of forty commands on a loaded machine: each waits for its own end
@pytest.mark.parametrize("page", RUN_HERE, ids=[page.path for page in RUN_HERE])
def test_the_commands_of_each_page_run_as_shown(
    page: Page, bus: Bus, tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    """In page order, in a sandbox of the page's own (tests/docs/sandbox.py): each exits with 0,
    each that runs until stopped became ready and stopped cleanly at the end."""
    sandbox = Sandbox.make(bus, tmp_path)
    if any(words(command.text)[:1] and words(command.text)[0] in NODE_TOOLS for command in page.commands):
        node: LocalNode = request.getfixturevalue("killable_node")
        node.up()
        tool_env = {**node.env(), "PATH": f"/usr/lib/rabbitmq/bin:{sandbox.env['PATH']}"}
        sandbox.tools.update(dict.fromkeys(NODE_TOOLS, tool_env))
    if page.path in MADE_FILES:
        MADE_FILES[page.path](sandbox.folder)
    try:
        ran = sandbox.run_page(page)
    finally:
        bus.accounts.extend(name for name in sandbox.users_made() if name not in bus.accounts)
    assert ran
