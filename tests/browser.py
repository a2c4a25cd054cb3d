"""A real headless Chromium (Debian's chromium and chromium-driver, which ``make`` installs) driven by selenium, for
tests of the pages semmap writes: what a page logged, every address it asked for, and pictures of its 3D canvas."""

from __future__ import annotations

import base64
import json
import shutil
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import pytest

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"
#: How the probe of this machine kind starts Chromium (as root: no sandbox; no connections of its own, which a
#: closed network refuses noisily), with WebGL drawn in software.
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--disable-quic",
         "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-dev-shm-usage", "--window-size=1280,1000")
#: Seconds a page may take to load and draw its 3D view (software WebGL on a busy machine).
DRAW_TIMEOUT_S = 120.0
#: The plotly view's WebGL canvas.
CANVAS = "div.js-plotly-plot .gl-container canvas"
#: Address schemes a page may load from without a network.
OFFLINE_SCHEMES = ("file:", "data:", "blob:", "about:", "chrome:", "chrome-untrusted:", "devtools:")


def chromium_or_skip() -> None:
    """Skip the calling test where Chromium, its driver or selenium is missing (``make`` installs all three)."""
    if shutil.which(CHROMIUM) is None or shutil.which(CHROMEDRIVER) is None:
        pytest.skip("Debian's chromium and chromium-driver are not installed (make installs them)")
    pytest.importorskip("selenium")


@contextmanager
def chromium() -> Iterator:
    """A headless Chromium with a fresh profile, logging its console and network, quit afterwards."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in FLAGS:
        options.add_argument(flag)
    profile = tempfile.mkdtemp(prefix="semmap-chromium-")
    options.add_argument(f"--user-data-dir={profile}")
    options.set_capability("goog:loggingPrefs", {"browser": "ALL", "performance": "ALL"})
    driver = webdriver.Chrome(options=options, service=Service(CHROMEDRIVER))
    try:
        yield driver
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)


def open_page(driver, page: Path) -> None:
    """Load ``page`` from disk and wait until its plotly views have drawn."""
    driver.get(page.resolve().as_uri())
    deadline = time.monotonic() + DRAW_TIMEOUT_S
    ready = ("return document.readyState === 'complete' && document.querySelectorAll(arguments[0]).length > 0 && "
             "Array.from(document.querySelectorAll('div.js-plotly-plot')).every(d => d._fullLayout)")
    while not driver.execute_script(ready, CANVAS):
        if time.monotonic() > deadline:
            raise AssertionError(f"{page}: the 3D view did not draw within {DRAW_TIMEOUT_S:.0f} s")
        time.sleep(0.25)
    settle(driver)


def settle(driver) -> None:
    """Wait for the next frames to be drawn (WebGL draws on animation frames, after plotly's own updates)."""
    driver.execute_async_script("const done = arguments[0]; requestAnimationFrame(() => requestAnimationFrame("
                                "() => setTimeout(done, 300)));")


def wait_for(driver, script: str, *args, timeout_s: float = 30.0) -> None:
    """Wait until ``script`` returns true in the page (e.g. plotly's state after a click), then for a drawn frame."""
    deadline = time.monotonic() + timeout_s
    while not driver.execute_script(script, *args):
        if time.monotonic() > deadline:
            raise AssertionError(f"the page never reached: {script}")
        time.sleep(0.1)
    settle(driver)


def canvas_shot(driver) -> np.ndarray:
    """An RGB picture of the largest 3D canvas on the page, as the user sees it."""
    from selenium.webdriver.common.by import By

    canvas = max(driver.find_elements(By.CSS_SELECTOR, CANVAS), key=lambda e: e.size["width"] * e.size["height"])
    driver.execute_script("arguments[0].scrollIntoView({block: 'center'})", canvas)
    settle(driver)
    png = np.frombuffer(base64.b64decode(canvas.screenshot_as_base64), np.uint8)
    return cv2.cvtColor(cv2.imdecode(png, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def console_errors(driver) -> list[str]:
    """The page's console messages at level SEVERE (errors, failed loads)."""
    return [e["message"] for e in driver.get_log("browser") if e["level"] == "SEVERE"]


def network_requests(driver) -> list[str]:
    """Every address the browser asked for since the last call, outside the offline schemes."""
    urls = [json.loads(e["message"])["message"]["params"]["request"]["url"]
            for e in driver.get_log("performance") if '"Network.requestWillBeSent"' in e["message"]]
    return [u for u in urls if not u.startswith(OFFLINE_SCHEMES)]


def colours_shown(image: np.ndarray, palette: dict[str, tuple[int, int, int]], *, min_pixels: int = 40,
                  tolerance: int = 6) -> set[str]:
    """The names in ``palette`` whose colour covers at least ``min_pixels`` pixels of ``image`` (within
    ``tolerance`` per channel: markers are drawn flat, only their edges blended)."""
    pixels = image.reshape(-1, 3).astype(np.int16)
    return {name for name, rgb in palette.items()
            if int((np.abs(pixels - np.asarray(rgb, np.int16)).max(axis=1) <= tolerance).sum()) >= min_pixels}
