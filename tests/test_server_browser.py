"""The page of ``geofill serve`` in a real headless Chromium (Debian's ``chromium`` and
``chromium-driver``, driven by Selenium): open a target and a reference, brush a stroke with mouse
events, Fill, wait, download, and check the downloaded image against the target; open the
reference in the editor, brush what must not be copied from it, and check that the request
carries its mask and the fill refused those pixels.

The browser is installed by this test's set-up when it is missing and we are root (``apt-get``);
the test is skipped, saying why, only when no Chromium can be had. Screenshots of the finished page
are written to ``test-artifacts/`` (``$GEOFILL_TEST_ARTIFACTS`` overrides the folder):
``server_page.png``, ``reference_mask.png``, ``page_result_<width>x<height>.png`` at three window
sizes and, with the real pairs, ``page_1440x900.jpg`` and ``page_390x844.jpg`` (docs/img)."""

from __future__ import annotations

import io
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
from geofill.server import jobs as jobs_module
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
    """A real uvicorn server with one worker on a free port: (base URL, app). Its jobs keep the
    uploads the page sent when they end (a server deletes them then), so that the tests read them."""
    app = create_app(ServerSettings(workers=1, temp_parent=str(tmp_path_factory.mktemp("serve"))))
    srv = _Server(uvicorn.Config(app, host="127.0.0.1", port=0, log_level="warning"))
    thread = threading.Thread(target=srv.run, daemon=True)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(jobs_module, "KEPT_FILES", _KEEP_EVERY_UPLOAD)
        thread.start()
        deadline = time.monotonic() + 60
        while not (srv.started and srv.servers) and time.monotonic() < deadline:
            time.sleep(0.05)
        port = srv.servers[0].sockets[0].getsockname()[1]
        yield f"http://127.0.0.1:{port}", app
        srv.should_exit = True
        thread.join(30)


class _KeepEveryUpload(frozenset):
    """Every file name is kept."""

    def __contains__(self, name: object) -> bool:
        return True


_KEEP_EVERY_UPLOAD = _KeepEveryUpload()


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


#: (canvas CSS width and height, open photo's width and height)
_SIZES = """const r = view.getBoundingClientRect(), b = state.doc.bitmap;
return [r.width, r.height, b.width, b.height];"""


def _offset(driver, x: float, y: float) -> tuple[int, int]:
    """Image px (x, y) of the fitted photo -> offset from the canvas centre (CSS px)."""
    w, h, pw, ph = driver.execute_script(_SIZES)
    scale = min(w / pw, h / ph)
    return round((x - pw / 2) * scale), round((y - ph / 2) * scale)


def _open(driver, url: str, target: Path, reference: Path):
    """The page loaded with its options, ``target`` open in the editor, ``reference`` added: the canvas."""
    driver.get(url)
    wait = WebDriverWait(driver, 30)
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, "#advanced-fields .field"))
    _upload(driver, "file-target", target)
    canvas = driver.find_element(By.ID, "view")
    wait.until(lambda d: canvas.is_displayed())
    _upload(driver, "file-refs", reference)
    wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#ref-list img")) == 1)
    return canvas


def _set_range(driver, slider, value: float) -> None:
    """A range input set to ``value`` as a drag would (its input event included)."""
    driver.execute_script(
        "arguments[0].value = arguments[1]; arguments[0].dispatchEvent(new Event('input'));", slider, value
    )


def _brush(driver, canvas, points: list[tuple[float, float]], size: int) -> None:
    """One stroke of the brush (slider ``size``) through ``points`` (image px)."""
    _set_range(driver, driver.find_element(By.ID, "brush-size"), size)
    (x0, y0), *rest = points
    chain = ActionChains(driver).move_to_element_with_offset(canvas, *_offset(driver, x0, y0))
    chain = chain.click_and_hold()
    for x, y in rest:
        chain = chain.move_to_element_with_offset(canvas, *_offset(driver, x, y))
    chain.release().perform()


def test_brush_fill_download_in_chromium(chromium, server, scene, tmp_path):
    url, app = server
    folder, target = scene
    downloads = tmp_path / "downloads"
    downloads.mkdir()
    driver = _driver(chromium, downloads)
    try:
        canvas = _open(driver, url, folder / "target.png", folder / "reference.png")
        wait = WebDriverWait(driver, 30)
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


def _slider_for(driver, image_px: float) -> int:
    """The brush slider value (CSS px) that paints ``image_px`` image pixels wide on the fitted photo."""
    w, h, pw, ph = driver.execute_script(_SIZES)
    return round(image_px * min(w / pw, h / ph))


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
        _brush(driver, canvas, [(160, 180), (240, 180), (320, 180)], _slider_for(driver, 64))
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
        _brush(driver, canvas, [(150, 180), (195, 180), (240, 180)], _slider_for(driver, 50))
        label = driver.find_element(By.CSS_SELECTOR, "#ref-list li span")
        assert label.text == "reference 1 · masked"
        # brush, eraser, clear and undo work on the reference's mask as on the hole
        driver.find_element(By.ID, "tool-eraser").click()
        _brush(driver, canvas, [(130, 180), (150, 180)], _slider_for(driver, 60))  # x < 165 goes
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


def _viewport(driver, width: int, height: int) -> None:
    """The page's viewport set to exactly ``width`` x ``height`` CSS px (a window's size is not)."""
    metrics = {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False}
    driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride", metrics)


#: The editor's geometry: the canvas's bitmap and CSS box, the photo as shown and the page's extent.
_LAYOUT = """
const r = view.getBoundingClientRect(), v = state.view, b = state.doc.bitmap, dpr = devicePixelRatio;
return {bitmap: [view.width, view.height], box: [r.width, r.height], bottom: r.bottom,
        shown: [b.width * v.scale / dpr, b.height * v.scale / dpr],
        fit: Math.min(view.width / b.width, view.height / b.height), scale: v.scale,
        page: [document.documentElement.scrollWidth, innerWidth, innerHeight]};
"""


def _settled_layout(driver) -> dict:
    """The editor's geometry once the canvas's bitmap has followed its box (a resize is observed)."""
    settled = """const r = view.getBoundingClientRect();
    return Math.abs(view.width - r.width) < 1 && Math.abs(view.height - r.height) < 1;"""
    WebDriverWait(driver, 5).until(lambda d: d.execute_script(settled))
    return driver.execute_script(_LAYOUT)


def _assert_editor_fits(layout: dict, min_share: float) -> None:
    """The photo is shown undistorted (bitmap and CSS box of one aspect within 1 %), fitted, on
    ``min_share`` of the viewport at least, all on the first screen, with no sideways scroll."""
    (bw, bh), (cw, ch) = layout["bitmap"], layout["box"]
    assert abs((bw / bh) / (cw / ch) - 1) < 0.01, layout
    assert layout["scale"] == pytest.approx(layout["fit"], rel=1e-9), layout
    width, inner_w, inner_h = layout["page"]
    assert width <= inner_w, layout
    shown_w, shown_h = layout["shown"]
    assert shown_w * shown_h >= min_share * inner_w * inner_h, layout
    assert layout["bottom"] <= inner_h, layout


def _pixel(driver, x: int, y: int) -> np.ndarray:
    """The canvas's RGB at the centre of image pixel (x, y) of the open photo."""
    script = """const v = state.view, [x, y] = arguments;
    const at = (t, offset) => Math.floor(offset + (t + 0.5) * v.scale);
    return [...ctx.getImageData(at(x, v.ox), at(y, v.oy), 1, 1).data];"""
    return np.array(driver.execute_script(script, x, y)[:3], int)


def _rows(driver, selector: str) -> list[str]:
    return driver.execute_script(
        "return [...document.querySelectorAll(arguments[0])].map((e) => e.dataset.key || e.dataset.section);",
        selector,
    )


def _assert_advanced_options(driver) -> None:
    """The options come grouped: the common keys first, then one group per section in the
    pipeline's order, each option with its description and its bounds; a change is marked and
    sent, Reset undoes it, the finder shows only what matches."""
    from geofill.server.schema import COMMON_KEYS, config_fields, config_sections

    driver.find_element(By.CSS_SELECTOR, "#advanced summary").click()
    assert _rows(driver, "#advanced-fields > .field") == list(COMMON_KEYS)
    sections = [name for name, _ in config_sections()]
    assert _rows(driver, "#advanced-fields > details") == [*sections, ""]
    unlocked = [f for f in config_fields() if not f.locked]
    assert len(_rows(driver, "#advanced-fields .field")) == len(unlocked)
    ratio = driver.find_element(By.CSS_SELECTOR, '.field[data-key="matching.ratio"]')
    assert ratio.find_element(By.TAG_NAME, "label").get_attribute("textContent") == "ratio"
    about, limits = (p.get_attribute("textContent") for p in ratio.find_elements(By.TAG_NAME, "p"))
    assert about == "Lowe's ratio test threshold." and limits == "Default: 0.8 · 0 to 1."
    focal = driver.find_element(By.CSS_SELECTOR, '.field[data-key="intrinsics.focal_px"] p.limits')
    expected = "Default: automatic · above 0, up to 1,000,000 · empty: automatic."
    assert focal.get_attribute("textContent") == expected
    # a setting that costs shows this server's cap as its allowed maximum
    side = driver.find_element(By.CSS_SELECTOR, '.field[data-key="working_max_side"]')
    assert side.find_element(By.TAG_NAME, "input").get_attribute("max") == "1280"
    limits = side.find_element(By.CSS_SELECTOR, "p.limits").get_attribute("textContent")
    assert limits == "Default: 1280 · 64 to 16,384 · this server allows at most 1280."
    features = driver.find_element(By.CSS_SELECTOR, '.field[data-key="matching.max_features"]')
    assert features.find_element(By.TAG_NAME, "input").get_attribute("min") == "1"
    assert "at most 4000 (0, no limit, is refused)" in features.get_attribute("textContent")

    matching = driver.find_element(By.CSS_SELECTOR, '#advanced-fields details[data-section="matching"]')
    matching.find_element(By.TAG_NAME, "summary").click()
    field = ratio.find_element(By.TAG_NAME, "input")
    field.clear()
    field.send_keys("0.7", Keys.TAB)
    assert "changed" in ratio.get_attribute("class")
    count = sum(f.section == "matching" and f.key not in COMMON_KEYS for f in unlocked)
    assert matching.find_element(By.CSS_SELECTOR, "summary .count").text == f"({count}, 1 changed)"
    assert driver.execute_script("return configOverrides()") == {"matching.ratio": 0.7}
    driver.find_element(By.ID, "advanced-reset").click()
    assert driver.execute_script("return configOverrides()") == {}

    finder = driver.find_element(By.ID, "advanced-filter")
    finder.send_keys("ratio")
    shown = driver.execute_script(
        "return state.fields.filter((f) => !f.row.hidden).map((f) => f.key + ' ' + f.description)"
    )
    assert len(shown) >= 3 and all("ratio" in text.lower() for text in shown), shown
    finder.send_keys(Keys.BACK_SPACE * len("ratio"))  # typed away: every option again
    assert driver.execute_script("return state.fields.filter((f) => !f.row.hidden).length") == len(unlocked)


def test_result_view_divider_errors_and_small_windows_in_chromium(chromium, server, scene, tmp_path):
    """After a fill the photo keeps its shape and stays fitted; left of the divider, labelled
    Before, is the photo, right of it the result; an error about a file goes once a good file
    loads; the advanced options are grouped and described; at 1440x900, 800x600 and 360x640 the
    editor shows the photo large, undistorted, without sideways scroll (panel and options included);
    on the phone-sized one two fingers zoom."""
    url, app = server
    folder, target = scene
    bad = tmp_path / "notimage.png"
    bad.write_bytes(b"this is not an image")
    Image.fromarray(np.zeros((100, 100), np.uint8)).save(tmp_path / "small_mask.png")
    hole = np.zeros((H, W), np.uint8)
    hole[150:210, 180:300] = 255  # over the magenta object (x 200-280, y 165-195)
    Image.fromarray(hole).save(tmp_path / "mask.png")
    driver = _driver(chromium, tmp_path)
    try:
        _viewport(driver, 1366, 768)
        driver.get(url)
        wait = WebDriverWait(driver, 30)
        wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, "#advanced-fields .field"))
        message = driver.find_element(By.ID, "message")

        _upload(driver, "file-target", bad)
        wait.until(lambda d: message.text)
        assert message.text.startswith("notimage.png: this browser cannot show it")
        _upload(driver, "file-target", folder / "target.png")
        wait.until(lambda d: d.find_element(By.ID, "view").is_displayed())
        assert message.text == ""
        _upload(driver, "file-mask", tmp_path / "small_mask.png")
        wait.until(lambda d: message.text)
        assert message.text == f"The mask is 100×100; the photo is {W}×{H}."
        _upload(driver, "file-mask", tmp_path / "mask.png")
        wait.until(lambda d: not message.text)
        _upload(driver, "file-refs", bad)
        wait.until(lambda d: message.text)
        _upload(driver, "file-refs", folder / "reference.png")
        wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#ref-list img")) == 1)
        assert message.text == ""

        _assert_advanced_options(driver)
        driver.find_element(By.CSS_SELECTOR, "#advanced summary").click()  # closed again

        driver.find_element(By.ID, "fill").click()
        job = _wait_for_fill(driver)
        # the result as shown, before any other change of size: undistorted and fitted
        _assert_editor_fits(_settled_layout(driver), 0.3)
        result = np.array(Image.open(app.state.jobs.get(job["id"]).folder / "result.png").convert("RGB"))

        # the divider starts at the hole's left edge: all of the fill shows
        split = driver.find_element(By.ID, "split")
        start = int(split.get_attribute("value"))
        assert start <= 100 * 180 / W
        # the canvas is scaled: it shows the fill's pixel there, give or take a pixel of resampling
        # (the default painter keeps texture, so a local mean is no stand-in for it)
        near = np.abs(result[179:182, 239:242].astype(int) - _pixel(driver, 240, 180)).mean(axis=2)
        assert near.min() < 8, near
        # at half-way: the photo (its magenta object) left, the result right
        _set_range(driver, split, 50)
        before, after = _pixel(driver, 225, 180), _pixel(driver, 255, 180)
        assert np.abs(before - target[180, 225]).mean() < 12 and target[180, 225].tolist() == [255, 0, 255]
        assert np.abs(after - result[180, 255]).mean() < 12
        assert np.abs(result[180, 255] - (255, 0, 255)).mean() > 60  # the result there differs
        words = driver.find_elements(By.CSS_SELECTOR, "#compare > span")
        assert [w.text for w in words] == ["Before", "After"]
        assert words[0].location["x"] < split.location["x"] < words[1].location["x"]

        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        for width, height, share in ((1440, 900, 0.5), (800, 600, 0.3), (360, 640, 0.3)):
            _viewport(driver, width, height)
            driver.execute_script("window.scrollTo(0, 0)")
            _assert_editor_fits(_settled_layout(driver), share)
            driver.save_screenshot(str(ARTIFACTS / f"page_result_{width}x{height}.png"))
            # every option open: still no sideways scroll, in the page or in the panel
            driver.execute_script("document.querySelectorAll('details').forEach((d) => { d.open = true; });")
            extents = driver.execute_script(
                """const a = document.querySelector('aside');
                return [document.documentElement.scrollWidth, innerWidth, a.scrollWidth, a.clientWidth];"""
            )
            assert extents[0] <= extents[1] and extents[2] <= extents[3], (width, extents)
            driver.execute_script("document.querySelectorAll('details').forEach((d) => { d.open = false; });")

        # on the phone-sized window two fingers zoom: spread from 40 to 140 px apart, 3.5x
        driver.execute_cdp_cmd("Emulation.setTouchEmulationEnabled", {"enabled": True, "maxTouchPoints": 2})
        left, top, w, h = driver.execute_script(
            "const r = view.getBoundingClientRect(); return [r.left, r.top, r.width, r.height];"
        )
        x, y = left + w / 2, top + h / 2
        fitted = driver.execute_script("return state.view.scale")
        _touch(driver, "touchStart", [(x - 20, y)])
        _touch(driver, "touchStart", [(x - 20, y), (x + 20, y)])
        for step in range(1, 6):
            _touch(driver, "touchMove", [(x - 20 - 10 * step, y), (x + 20 + 10 * step, y)])
        _touch(driver, "touchEnd", [])
        view = driver.execute_script("return [state.view.scale, state.target.layer.ops.length]")
        assert view == [pytest.approx(fitted * 3.5, rel=1e-6), 1]  # zoomed; the hole unchanged
        # on a photo being edited, the stroke the first finger began is dropped when a second comes
        driver.find_element(By.ID, "keep-editing").click()
        WebDriverWait(driver, 10).until(lambda d: d.execute_script("return state.result === null"))
        driver.execute_script("window.scrollTo(0, 0)")
        _touch(driver, "touchStart", [(x - 40, y)])
        _touch(driver, "touchMove", [(x - 20, y)])
        _touch(driver, "touchStart", [(x - 20, y), (x + 20, y)])
        _touch(driver, "touchMove", [(x - 30, y), (x + 30, y)])
        _touch(driver, "touchEnd", [])
        hole = """const m = state.target.layer.mask;
        return m.getContext('2d').getImageData(0, 0, m.width, m.height).data.some((v) => v > 0);"""
        assert driver.execute_script("return state.target.layer.ops.length") == 0
        assert not driver.execute_script(hole)
    finally:
        driver.quit()


def _touch(driver, kind: str, points: list[tuple[float, float]]) -> None:
    """One touch event (CDP), ``points`` the fingers on the screen (CSS px), one id each."""
    fingers = [{"x": x, "y": y, "id": i} for i, (x, y) in enumerate(points)]
    driver.execute_cdp_cmd("Input.dispatchTouchEvent", {"type": kind, "touchPoints": fingers})


@pytest.mark.slow
def test_a_real_photo_at_desktop_and_phone_sizes_in_chromium(chromium, server, pairs_dir, tmp_path):
    """Berlin cathedral's steps (a real DEV pair, 1280x960): two passers-by brushed over and
    filled; at 1440x900 and at 390x844 the result shows undistorted, fitted, large and without
    sideways scroll. Its screenshots (``page_1440x900.jpg``, ``page_390x844.jpg``) are the
    documentation's (docs/img)."""
    url, _ = server
    pair = pairs_dir / "dev_opensfm_berlin_01_02"
    driver = _driver(chromium, tmp_path)
    try:
        _viewport(driver, 1440, 900)
        canvas = _open(driver, url, pair / "target.jpg", pair / "source.jpg")
        _brush(driver, canvas, [(405, 760), (405, 830), (410, 900)], _slider_for(driver, 120))  # walking man
        _brush(driver, canvas, [(712, 750), (716, 820), (720, 890)], _slider_for(driver, 130))  # woman
        driver.find_element(By.ID, "fill").click()
        _wait_for_fill(driver)
        assert "% from reference 1" in driver.find_element(By.ID, "summary").text
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        for width, height, share in ((1440, 900, 0.5), (390, 844, 0.25)):
            _viewport(driver, width, height)
            driver.execute_script("window.scrollTo(0, 0)")
            _assert_editor_fits(_settled_layout(driver), share)
            shot = Image.open(io.BytesIO(driver.get_screenshot_as_png())).convert("RGB")
            shot.save(ARTIFACTS / f"page_{width}x{height}.jpg", quality=90)
    finally:
        driver.quit()
