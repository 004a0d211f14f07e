from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.console.support import Browser, start_chromium


@pytest.fixture(scope="session")
def chromium() -> Iterator[Browser]:
    """Headless chromium, one per test process."""
    driver = start_chromium()
    try:
        yield Browser(driver)
    finally:
        driver.quit()


@pytest.fixture
def browser(chromium: Browser) -> Browser:
    """The process's chromium, with no cookies and a blank page."""
    chromium.reset()
    return chromium
