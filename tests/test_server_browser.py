"""The page of ``geofill serve`` in a real headless Chromium (Debian's ``chromium`` and
``chromium-driver``, driven by Selenium): open a target and a reference, brush a stroke with mouse
events, Fill, wait, download, and check the downloaded image against the target.

The browser is installed by this test's set-up when it is missing and we are root (``apt-get``);
the test is skipped, saying why, only when no Chromium can be had. A screenshot of the finished page
is written to ``test-artifacts/server_page.png`` (``$GEOFILL_TEST_ARTIFACTS`` overrides the folder)."""

from __future__ import annotations

import os
import shutil
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("fastapi", reason="the server extra is not installed")
pytest.importorskip("selenium", reason="selenium is not installed")
import uvicorn
from PIL import Image
from selenium import webdriver
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.by import By
from selenium.webdriver.common.keys import Keys
from selenium.webdriver.support.ui import WebDriverWait

from geofill.io import read_mask
from geofill.server.app import create_app
from geofill.server.jobs import ServerSettings
from geofill.synthetic import make_pair

REPO = Path(__file__).resolve().parents[1]
ARTIFACTS = Path(os.environ.get("GEOFILL_TEST_ARTIFACTS", REPO / "test-artifacts"))
W, H = 480, 360


def _chromium() -> tuple[str, str] | None:
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    driver = shutil.which("chromedriver")
    return (browser, driver) if browser and driver else None


@pytest.fixture(scope="module")
def chromium() -> tuple[str, str]:
    """(browser, driver) paths; installs Debian's packages when missing and root."""
    found = _chromium()
    if found is None and hasattr(os, "geteuid") and os.geteuid() == 0 and shutil.which("apt-get"):
        env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
        subprocess.run(["apt-get", "update", "-qq"], env=env, capture_output=True, check=False, timeout=600)
        subprocess.run(
            ["apt-get", "install", "-y", "-qq", "chromium", "chromium-driver"],
            env=env, capture_output=True, check=False, timeout=900,
        )  # fmt: skip
        found = _chromium()
    if found is None:
        reason = (
            "no Chromium: `apt-get install -y chromium chromium-driver` (as root) was impossible or failed"
        )
        print(f"SKIPPED browser test: {reason}")
        pytest.skip(reason)
    return found


class _Server(uvicorn.Server):
    def install_signal_handlers(self) -> None:  # runs in a thread: the test process keeps its handlers
        pass


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """A real uvicorn server with one worker on a free port: (base URL, app)."""
    app = create_app(ServerSettings(workers=1, temp_parent=str(tmp_path_factory.mktemp("serve"))))
    srv = _Server(uvicorn.Config(app, host="127.0.0.1", port=0, log_level="warning"))
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 60
    while not (srv.started and srv.servers) and time.monotonic() < deadline:
        time.sleep(0.05)
    port = srv.servers[0].sockets[0].getsockname()[1]
    yield f"http://127.0.0.1:{port}", app
    srv.should_exit = True
    thread.join(30)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """Target (with a flat magenta object where the stroke will go) and reference as PNG files."""
    pair = make_pair(seed=1, width=W, height=H)
    folder = tmp_path_factory.mktemp("scene")
    target = pair.target.copy()
    target[165:195, 200:280] = (255, 0, 255)  # inside the stroke below
    Image.fromarray(target).save(folder / "target.png")
    Image.fromarray(pair.source).save(folder / "reference.png")
    return folder, target


def _driver(chromium: tuple[str, str], downloads: Path) -> webdriver.Chrome:
    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium[0]
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1366,768"):
        opts.add_argument(arg)
    opts.add_experimental_option(
        "prefs", {"download.default_directory": str(downloads), "download.prompt_for_download": False}
    )
    return webdriver.Chrome(options=opts, service=webdriver.ChromeService(executable_path=chromium[1]))


def _upload(driver, input_id: str, path: Path) -> None:
    field = driver.find_element(By.ID, input_id)
    driver.execute_script("arguments[0].hidden = false;", field)  # a hidden input takes no keys
    field.send_keys(str(path))
    driver.execute_script("arguments[0].hidden = true;", field)


def test_brush_fill_download_in_chromium(chromium, server, scene, tmp_path):
    url, app = server
    folder, target = scene
    downloads = tmp_path / "downloads"
    downloads.mkdir()
    driver = _driver(chromium, downloads)
    try:
        driver.get(url)
        wait = WebDriverWait(driver, 30)
        wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, "#advanced-fields fieldset"))
        _upload(driver, "file-target", folder / "target.png")
        canvas = driver.find_element(By.ID, "view")
        wait.until(lambda d: canvas.is_displayed())
        _upload(driver, "file-refs", folder / "reference.png")
        wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#ref-list img")) == 1)
        assert driver.find_element(By.ID, "fill").get_attribute("disabled")  # no hole yet

        # a horizontal stroke across the magenta object, in image pixels mapped to the canvas
        rect = driver.execute_script(
            "const r = arguments[0].getBoundingClientRect(); return [r.width, r.height];", canvas
        )
        scale = min(rect[0] / W, rect[1] / H)

        def offset(x: float, y: float) -> tuple[int, int]:  # image px -> offset from the canvas centre
            return round((x - W / 2) * scale), round((y - H / 2) * scale)

        size = driver.find_element(By.ID, "brush-size")
        driver.execute_script(
            "arguments[0].value = 70; arguments[0].dispatchEvent(new Event('input'));", size
        )
        chain = ActionChains(driver).move_to_element_with_offset(canvas, *offset(190, 180)).click_and_hold()
        for x in range(200, 300, 10):
            chain = chain.move_to_element_with_offset(canvas, *offset(x, 180))
        chain.release().perform()

        fill = driver.find_element(By.ID, "fill")
        assert fill.is_enabled()
        # keyboard: undo empties the hole, redo brings it back; + zooms, 0 fits again
        keys = ActionChains(driver)
        keys.key_down(Keys.CONTROL).send_keys("z").key_up(Keys.CONTROL).perform()
        assert not fill.is_enabled()
        keys.key_down(Keys.CONTROL).send_keys("y").key_up(Keys.CONTROL).perform()
        assert fill.is_enabled()
        zoom = driver.find_element(By.ID, "zoom-value")
        fitted = zoom.text
        ActionChains(driver).send_keys("+").perform()
        assert int(zoom.text.split()[0]) > int(fitted.split()[0])
        ActionChains(driver).send_keys("0").perform()
        assert zoom.text == fitted

        fill.click()
        WebDriverWait(driver, 600).until(
            lambda d: d.find_element(By.ID, "result").is_displayed() or d.find_element(By.ID, "message").text
        )
        assert driver.find_element(By.ID, "message").text == ""
        summary = driver.find_element(By.ID, "summary").text
        assert summary.startswith("Hole filled: ") and "% from reference 1" in summary
        driver.find_element(By.ID, "show-coverage").click()
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        driver.save_screenshot(str(ARTIFACTS / "server_page.png"))

        driver.find_element(By.ID, "download").click()
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not list(downloads.glob("*.png")):
            time.sleep(0.1)
        (path,) = list(downloads.glob("*.png"))

        # keep editing from the result: the result becomes the photo, with an empty hole
        driver.find_element(By.ID, "keep-editing").click()
        wait.until(lambda d: not d.find_element(By.ID, "result").is_displayed())
        assert not fill.is_enabled() and not driver.find_element(By.ID, "compare").is_displayed()
    finally:
        driver.quit()

    result = np.array(Image.open(path).convert("RGB"))
    assert result.shape == target.shape
    jobs = app.state.jobs
    (job,) = [jobs.get(i) for i in list(jobs._jobs)]  # the one job the page made
    hole = read_mask(job.folder / "mask")
    assert 0.02 < hole.mean() < 0.2
    ys, xs = np.nonzero(hole)
    assert abs(xs.mean() - 245) < 15 and abs(ys.mean() - 180) < 10  # where the stroke went
    assert np.array_equal(result[~hole], target[~hole])  # every other pixel is the target's
    object_px = hole.copy()
    object_px[:165], object_px[195:], object_px[:, :200], object_px[:, 280:] = False, False, False, False
    magenta = np.abs(result[object_px].astype(int) - (255, 0, 255)).mean()
    assert magenta > 60  # the object under the stroke is gone
