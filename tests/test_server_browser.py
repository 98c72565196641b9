"""The page of ``geofill serve`` in a real headless Chromium (Debian's ``chromium`` and
``chromium-driver``, driven by Selenium): open a target and a reference, brush a stroke with mouse
events, Fill, wait, download, and check the downloaded image against the target; open the
reference in the editor, brush what must not be copied from it, and check that the request
carries its mask and the fill refused those pixels.

The browser is installed by this test's set-up when it is missing and we are root (``apt-get``);
the test is skipped, saying why, only when no Chromium can be had. Screenshots of the finished page
are written to ``test-artifacts/server_page.png`` and ``test-artifacts/reference_mask.png``
(``$GEOFILL_TEST_ARTIFACTS`` overrides the folder)."""

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
#: The hole's stroke (image px): across the target's object.
STROKE = [(190, 180), *((x, 180) for x in range(200, 300, 10))]


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


def _driver(chromium: tuple[str, str], downloads: Path, size: str = "1366,768") -> webdriver.Chrome:
    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium[0]
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", f"--window-size={size}"):
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


def _offset(driver, canvas, x: float, y: float) -> tuple[int, int]:
    """Image px (x, y) of the fitted W x H photo -> offset from the canvas centre (CSS px)."""
    w, h = driver.execute_script(
        "const r = arguments[0].getBoundingClientRect(); return [r.width, r.height];", canvas
    )
    scale = min(w / W, h / H)
    return round((x - W / 2) * scale), round((y - H / 2) * scale)


def _brush(driver, canvas, points: list[tuple[float, float]], size: int) -> None:
    """One stroke of the brush (slider ``size``) through ``points`` (image px)."""
    slider = driver.find_element(By.ID, "brush-size")
    driver.execute_script(
        "arguments[0].value = arguments[1]; arguments[0].dispatchEvent(new Event('input'));", slider, size
    )
    (x0, y0), *rest = points
    chain = ActionChains(driver).move_to_element_with_offset(canvas, *_offset(driver, canvas, x0, y0))
    chain = chain.click_and_hold()
    for x, y in rest:
        chain = chain.move_to_element_with_offset(canvas, *_offset(driver, canvas, x, y))
    chain.release().perform()


def test_brush_fill_download_in_chromium(chromium, server, scene, tmp_path):
    url, app = server
    folder, target = scene
    downloads = tmp_path / "downloads"
    downloads.mkdir()
    driver = _driver(chromium, downloads)
    try:
        driver.get(url)
        wait = WebDriverWait(driver, 30)
        wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, "#advanced-fields .field"))
        _upload(driver, "file-target", folder / "target.png")
        canvas = driver.find_element(By.ID, "view")
        wait.until(lambda d: canvas.is_displayed())
        _upload(driver, "file-refs", folder / "reference.png")
        wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#ref-list img")) == 1)
        assert driver.find_element(By.ID, "fill").get_attribute("disabled")  # no hole yet

        # a horizontal stroke across the magenta object, in image pixels mapped to the canvas
        _brush(driver, canvas, STROKE, 70)

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


@pytest.fixture(scope="module")
def masked_scene(tmp_path_factory):
    """Target with a flat magenta object (x 120-360, y 140-220) that hides what the reference shows,
    and the reference, as PNG files."""
    pair = make_pair(seed=1, width=W, height=H)
    folder = tmp_path_factory.mktemp("masked_scene")
    target = pair.target.copy()
    target[140:220, 120:360] = (255, 0, 255)
    Image.fromarray(target).save(folder / "target.png")
    Image.fromarray(pair.source).save(folder / "reference.png")
    return folder


#: Records the field names of every form the page posts (the request the server receives).
_RECORD_FORMS = """
window.sentForms = [];
const originalFetch = window.fetch;
window.fetch = (url, options) => {
  if (options && options.body instanceof FormData) window.sentForms.push([...options.body.keys()]);
  return originalFetch(url, options);
};
"""


def _slider_for(driver, canvas, image_px: float) -> int:
    """The brush slider value (CSS px) that paints ``image_px`` image pixels wide on the fitted photo."""
    w, h = driver.execute_script(
        "const r = arguments[0].getBoundingClientRect(); return [r.width, r.height];", canvas
    )
    return round(image_px * min(w / W, h / H))


def _wait_for_fill(driver, timeout_s: float = 600) -> dict:
    """Wait until the page shows a fill's result (or a message); that job as the page got it."""
    done = "return state.job === null && (state.result !== null || $('message').textContent !== '')"
    WebDriverWait(driver, timeout_s).until(lambda d: d.execute_script(done))
    assert driver.find_element(By.ID, "message").text == ""
    return driver.execute_script("return state.result.data")


def test_reference_mask_brushed_in_chromium(chromium, server, masked_scene, tmp_path):
    """Open the reference from its thumbnail, brush in it what must not be copied, fill: the request
    carries source_mask_1 with that stroke, the job refuses those pixels; clear the reference's mask,
    fill again: more of the hole comes from the reference."""
    url, app = server
    folder = masked_scene
    driver = _driver(chromium, tmp_path, size="1280,960")  # the screenshot shows the whole panel
    try:
        driver.get(url)
        wait = WebDriverWait(driver, 30)
        wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, "#advanced-fields .field"))
        driver.execute_script(_RECORD_FORMS)
        _upload(driver, "file-target", folder / "target.png")
        canvas = driver.find_element(By.ID, "view")
        wait.until(lambda d: canvas.is_displayed())
        _upload(driver, "file-refs", folder / "reference.png")
        wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#ref-list .thumb")) == 1)
        label = driver.find_element(By.CSS_SELECTOR, "#ref-list li span")
        assert label.text == "reference 1" and driver.find_element(By.ID, "refs-hint").is_displayed()
        # the hole: over the whole object
        _brush(driver, canvas, [(160, 180), (240, 180), (320, 180)], _slider_for(driver, canvas, 64))
        fill = driver.find_element(By.ID, "fill")
        assert fill.is_enabled()

        # the reference in the editor: a stroke over what the hole would take from it
        driver.find_element(By.CSS_SELECTOR, "#ref-list .thumb").click()
        editing = driver.find_element(By.ID, "editing")
        assert editing.is_displayed() and "Reference 1 (reference.png)" in editing.text
        assert driver.find_element(By.ID, "tools-title").text == "Mark what not to copy from reference 1"
        assert (
            driver.find_element(By.CSS_SELECTOR, "#ref-list .thumb").get_attribute("aria-pressed") == "true"
        )
        assert not driver.find_element(By.ID, "undo").is_enabled()  # the reference's own history: empty
        _brush(driver, canvas, [(150, 180), (195, 180), (240, 180)], _slider_for(driver, canvas, 50))
        label = driver.find_element(By.CSS_SELECTOR, "#ref-list li span")
        assert label.text == "reference 1 · masked"
        # brush, eraser, clear and undo work on the reference's mask as on the hole
        driver.find_element(By.ID, "tool-eraser").click()
        _brush(driver, canvas, [(130, 180), (150, 180)], _slider_for(driver, canvas, 60))  # x < 165 goes
        driver.find_element(By.ID, "tool-brush").click()
        driver.find_element(By.ID, "clear").click()
        assert driver.find_element(By.CSS_SELECTOR, "#ref-list li span").text == "reference 1"
        ActionChains(driver).key_down(Keys.CONTROL).send_keys("z").key_up(Keys.CONTROL).perform()
        assert driver.find_element(By.CSS_SELECTOR, "#ref-list li span").text == "reference 1 · masked"
        ActionChains(driver).key_down(Keys.CONTROL).send_keys("z").key_up(Keys.CONTROL).perform()
        assert driver.find_element(By.CSS_SELECTOR, "#ref-list li span").text == "reference 1 · masked"
        ActionChains(driver).key_down(Keys.CONTROL).send_keys("y").key_up(Keys.CONTROL).perform()
        counts = driver.execute_script(
            "return [state.refs[0].layer.ops.length, state.target.layer.ops.length]"
        )
        assert counts == [2, 1]  # stroke and eraser stroke on the reference; the hole's one stroke

        # back to the photo: the hole is as it was
        driver.find_element(By.ID, "back-to-photo").click()
        assert not editing.is_displayed()
        assert driver.find_element(By.ID, "tools-title").text == "1. Mark the hole"
        fill.click()
        masked_job = _wait_for_fill(driver)
        summary = driver.find_element(By.ID, "summary").text
        assert "masked in the references" in summary, summary
        assert not fill.is_enabled()  # nothing changed since this fill

        # the reference open after the fill: what the documentation shows
        driver.find_element(By.CSS_SELECTOR, "#ref-list .thumb").click()
        assert editing.is_displayed() and not driver.find_element(By.ID, "compare").is_displayed()
        driver.execute_script("document.querySelector('aside').scrollTop = 0;")
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        driver.save_screenshot(str(ARTIFACTS / "reference_mask.png"))

        # without the reference's mask the same hole takes more from it
        driver.find_element(By.ID, "clear").click()
        assert fill.is_enabled() and fill.text == "Fill again"
        driver.find_element(By.ID, "back-to-photo").click()
        assert driver.find_element(By.ID, "compare").is_displayed()  # the result is shown again
        fill.click()
        WebDriverWait(driver, 600).until(
            lambda d: d.execute_script("return state.result.data.id") != masked_job["id"]
        )
        plain_job = _wait_for_fill(driver)
        sent = driver.execute_script("return window.sentForms")
    finally:
        driver.quit()

    assert sent == [["target", "mask", "sources", "source_mask_1"], ["target", "mask", "sources"]]
    jobs = app.state.jobs
    masked, plain = jobs.get(masked_job["id"]), jobs.get(plain_job["id"])
    assert masked.spec.source_masks == (1,) and plain.spec.source_masks == ()
    ref_mask = read_mask(masked.folder / "source-mask-1")
    assert abs(np.nonzero(ref_mask)[0].mean() - 180) < 5 and ref_mask[175:185, 180:260].all()  # the stroke
    assert not ref_mask[:, :160].any()  # less what the eraser took
    assert not (plain.folder / "source-mask-1").exists()
    hole = read_mask(masked.folder / "mask")
    assert hole[150:210, 160:320].all() and not hole[:, :120].any()  # not the reference's strokes
    assert np.array_equal(hole, read_mask(plain.folder / "mask"))
    refused = masked_job["report"]["refused_fraction"]
    assert refused["masked"] > 0.1, refused
    assert plain_job["report"]["refused_fraction"].get("masked", 0.0) == 0.0
    from_ref = masked_job["report"]["supplied_fraction"][0], plain_job["report"]["supplied_fraction"][0]
    assert from_ref[0] < from_ref[1] - 0.1, from_ref
    assert masked_job["source_masks"] == [1]
