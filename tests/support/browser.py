"""Headless Chromium for the browser tests (Debian's chromium + chromedriver, driven by Selenium): a fresh profile
per browser, a screenshot of the page when a test fails."""

from __future__ import annotations

import shutil
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from tests.support import waits

CHROMIUM = pytest.mark.skipif(
    not (Path("/usr/bin/chromium").exists() and Path("/usr/bin/chromedriver").exists()),
    reason="needs Debian's chromium and chromium-driver (apt-get install chromium chromium-driver)")


def _chrome(profile: Path, precise_memory: bool = False) -> Any:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = "/usr/bin/chromium"
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--no-first-run", f"--user-data-dir={profile}", "--window-size=1280,1000"):
        options.add_argument(arg)
    if precise_memory:
        options.add_argument("--enable-precise-memory-info")  # else performance.memory is coarse and delayed
    return webdriver.Chrome(options=options, service=Service("/usr/bin/chromedriver"))


@contextmanager
def browser(tmp_path: Path, name: str, precise_memory: bool = False) -> Iterator[Any]:
    """A fresh headless Chromium; on failure a screenshot lands in ``tmp_path`` (path printed); always quit."""
    profile = Path(tempfile.mkdtemp(prefix="chromium-profile-"))
    driver = _chrome(profile, precise_memory)
    driver.set_page_load_timeout(20)
    try:
        yield driver
    except BaseException:
        shot = tmp_path / f"{name}-failure.png"
        try:
            driver.save_screenshot(str(shot))
            print(f"\nscreenshot of the failing page: {shot}")
            logs = driver.get_log("browser")
            if logs:
                print("browser console:", *[f"  {e.get('level')} {e.get('message')}" for e in logs[-20:]], sep="\n")
        except Exception as err:  # the browser may be what failed; the original error matters more
            print(f"\nno screenshot ({err})")
        raise
    finally:
        try:
            driver.quit()
        except Exception:
            pass  # a test may already have closed it (the page-close test does)
        shutil.rmtree(profile, ignore_errors=True)


def wait_until(what: str, check: Callable[[], Any], timeout: float = 10.0, period: float = 0.1) -> Any:
    """:func:`tests.support.waits.wait_until` at a browser's pace: each look is a WebDriver round trip, which
    competes with the page's own timers (and the latencies measured from them) for the machine's two cores."""
    return waits.wait_until(what, check, timeout, period)


# -- the dashboard page, as the browser tests drive it -------------------------------------------------------

def login(driver: Any, url: str, user: str, password: str) -> None:
    from selenium.webdriver.common.by import By

    driver.get(url)
    wait_until("the derived WebSocket URL", lambda: driver.find_element(By.ID, "ws-url").get_attribute("value"))
    driver.find_element(By.ID, "username").send_keys(user)
    driver.find_element(By.ID, "password").send_keys(password)
    driver.find_element(By.ID, "connect").click()


def logged_in(driver: Any, user: str) -> None:
    wait_until(f"{user} connected", lambda: driver.execute_script(
        "return document.getElementById('conn').dataset.state") == "connected")


def robot_row(driver: Any, robot: str) -> dict[str, str] | None:
    """The fleet row of ``robot`` as {column: text}, or None when the page shows no such row."""
    return driver.execute_script("""
        const tr = document.querySelector(`#fleet tbody tr[data-robot="${arguments[0]}"]`);
        if (!tr) return null;
        const out = {};
        for (const td of tr.cells) out[td.className] = td.textContent;
        return out;""", robot)


def visible(driver: Any, element_id: str) -> bool:
    from selenium.webdriver.common.by import By

    return driver.find_element(By.ID, element_id).is_displayed()


def no_console_errors(driver: Any) -> None:
    """The page logged no error (an uncaught exception, a refused script or socket) to the browser console."""
    severe = [e["message"] for e in driver.get_log("browser") if e.get("level") == "SEVERE"]
    assert not severe, "browser console errors:\n" + "\n".join(severe)


def click_css(driver: Any, selector: str, timeout: float = 10.0) -> None:
    """A real click on the element ``selector`` names, found afresh for every try: a list the page rebuilds (the
    attention list, every half second while texts change) replaces its elements between a find and a click, and a
    held reference goes stale. Retries only on a stale or not-yet-present element; anything else fails at once."""
    from selenium.common.exceptions import NoSuchElementException, StaleElementReferenceException
    from selenium.webdriver.common.by import By

    deadline = time.monotonic() + timeout
    while True:
        try:
            click(driver, driver.find_element(By.CSS_SELECTOR, selector))
            return
        except (StaleElementReferenceException, NoSuchElementException):
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def click(driver: Any, element: Any) -> None:
    """Scroll ``element`` to the middle first: the sticky header (and a phone's stop bar at the bottom) would take
    a click at the edge."""
    driver.execute_script("arguments[0].scrollIntoView({block: 'center'})", element)
    element.click()
