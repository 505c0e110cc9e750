"""The results web page against a real `holo serve`: its security headers and API routes over HTTP,
then the page itself in headless Chromium (Debian's chromium and chromium-driver, driven by selenium): sign in
with a token, upload a scene whose folder is named like an XSS attempt, see the estimate, submit a small job,
watch it finish over the live events, move the focus slider and see the picture change, view the job with a
read-only token. Nothing the service says may run as HTML: the scene's name and a display's heartbeat message
hold markup that must stay text.

``HOLO_WEB_SCREENSHOTS=DIR`` makes the browser test save its screenshots there (with the XSS test's scene
name: the committed ones in docs/ come from scripts/web_screenshots.py and a real scene).
"""

from __future__ import annotations

import io
import os
import re
import shutil
import zipfile
from fnmatch import fnmatch
from html.parser import HTMLParser
from pathlib import Path

import pytest
import tomllib

from service.api.web import DOCS_CSP, WEB_DIR
from tests.service.helpers import REPO, SMALL_JOB, wait_for, wait_state

pytestmark = pytest.mark.slow  # headless Chromium; tests/service/test_units.py covers the page's API

XSS_FOLDER = "<img src=x onerror=window.__xss=1>"
XSS_MESSAGE = "<script>window.__xss=2</script><img src=x onerror=\"window.__xss=3\"> projector warm"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")


def _xss_bundle(tmp: Path) -> bytes:
    """A zip with the demo scene in a folder named like markup, and a text file beside it (so the folder is
    kept as part of the entry's name)."""
    from holocore.scene.demo import write_demo_scene

    folder = tmp / "bundle"
    write_demo_scene(folder / XSS_FOLDER)
    (folder / "notes.txt").write_text("a scene whose folder name is markup\n")
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for p in sorted(folder.rglob("*")):
            if p.is_file():
                zf.write(p, p.relative_to(folder).as_posix())
    return buf.getvalue()


@pytest.fixture(scope="module")
def scene(server, tmp_path_factory):
    """The XSS-named demo scene, uploaded, with its plan ready."""
    data = _xss_bundle(tmp_path_factory.mktemp("web"))
    with server.client("submit") as c:
        r = c.post("/v1/scenes", files={"bundle": ("b.zip", data, "application/zip")},
                   data={"entry": f"{XSS_FOLDER}/scene.xml"})
        assert r.status_code in (200, 201), r.text
        sc = r.json()
        wait_for(lambda: c.get(f"/v1/scenes/{sc['id']}").json()["plan_state"] in ("ready", "failed"),
                 timeout=90, what="the scene's plan")
    return {**sc, "zip": data}


# ---- over HTTP ------------------------------------------------------------------------------------------------
class _Tags(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict]] = []
        self.script_text = ""
        self._in_script = False

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))
        self._in_script = tag == "script"

    def handle_endtag(self, tag):
        self._in_script = False

    def handle_data(self, data):
        if self._in_script:
            self.script_text += data


def test_page_is_served_with_a_strict_content_security_policy(server):
    with server.client(None) as c:
        r = c.get("/")
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
        csp = r.headers["content-security-policy"]
        assert "default-src 'self'" in csp and "frame-ancestors 'none'" in csp and "object-src 'none'" in csp
        assert "unsafe-inline" not in csp and "unsafe-eval" not in csp
        assert r.headers["x-content-type-options"] == "nosniff" and r.headers["x-frame-options"] == "DENY"
        page = _Tags()
        page.feed(r.text)
        scripts = [a for t, a in page.tags if t == "script"]
        assert scripts and all(a.get("src", "").startswith("/web/") and a.get("type") == "module" for a in scripts)
        assert not page.script_text.strip(), "no inline script"
        assert not [(t, k) for t, a in page.tags for k in a if k.startswith("on")], "no inline event handlers"
        for name in sorted(p.name for p in WEB_DIR.glob("*.js")):  # every module of the page
            js = c.get(f"/web/{name}")
            assert js.status_code == 200 and js.headers["content-type"].startswith("text/javascript")
            assert "innerHTML" not in js.text and "outerHTML" not in js.text and "insertAdjacentHTML" not in js.text
            assert "eval(" not in js.text and "document.write" not in js.text
        assert c.get("/web/style.css").headers["content-type"].startswith("text/css")
        etag = c.get("/web/app.js").headers["etag"]
        assert c.get("/web/app.js", headers={"If-None-Match": etag}).status_code == 304
        for bad in ("/web/..%2fapi%2fweb.py", "/web/web.py", "/web/.hidden.js", "/web/APP.JS"):
            assert c.get(bad).status_code == 404, bad
        api = c.get("/v1/jobs")  # 401, still with the headers
        assert api.status_code == 401 and api.headers["content-security-policy"].startswith("default-src 'none'")
        assert api.headers["x-content-type-options"] == "nosniff"
        docs = c.get("/docs")  # the API index: plain HTML from this origin, nothing from a CDN, never framed
        assert docs.status_code == 200 and docs.headers["content-security-policy"] == DOCS_CSP
        assert "<script" not in docs.text and "cdn" not in docs.text and "/v1/jobs" in docs.text


def test_web_files_are_package_data():
    """Every file of service/web is matched by pyproject's package-data, so `pip install` ships the page."""
    conf = tomllib.loads((REPO / "pyproject.toml").read_text())
    globs = conf["tool"]["setuptools"]["package-data"]["service"]
    files = [p.relative_to(WEB_DIR.parent).as_posix() for p in WEB_DIR.iterdir() if p.is_file()]
    assert {"web/index.html", "web/app.js", "web/api.js", "web/dom.js", "web/style.css"} <= set(files)
    assert all(any(fnmatch(f, g) for g in globs) for f in files), (files, globs)


def test_whoami_and_display_profiles(server):
    with server.client("reader") as c:
        me = c.get("/v1/whoami").json()
        assert me["scopes"] == ["read"] and me["may_submit"] is False and me["owner"] == "default"
        prof = c.get("/v1/display-profiles").json()
        assert prof["default"] == "paper" and prof["profiles"][0]["optics"]["resolution_hw"] == [1080, 1920]
    with server.client("submit") as c:
        assert c.get("/v1/whoami").json()["may_submit"] is True
    with server.client(None) as c:
        assert c.get("/v1/whoami").status_code == 401


def test_estimate_is_a_dry_run_with_the_submit_checks(server, scene):
    body = {"scene_id": scene["id"], **SMALL_JOB, "frames": 1}
    with server.client("submit") as c:
        before = len(c.get("/v1/jobs", params={"limit": 500}).json()["jobs"])
        est = c.post("/v1/jobs/estimate", json=body)
        assert est.status_code == 200, est.text
        e = est.json()
        assert e["estimate"]["seconds"] > 0 and e["estimate"]["memory"]["peak_bytes"] > 0 and e["reuses"] is None
        assert e["optics"]["frames"] == 1 and e["optics"]["resolution_hw"] == [64, 64]
        assert len(c.get("/v1/jobs", params={"limit": 500}).json()["jobs"]) == before, "no job was created"
        # the same checks as POST /v1/jobs
        assert c.post("/v1/jobs/estimate", json={**body, "scene_id": "snope"}).status_code == 422
        big = c.post("/v1/jobs/estimate", json={**body, "optics": {"resolution_hw": [5000, 64]}})
        assert big.status_code == 422 and "at most 4096" in big.json()["detail"]
        assert c.post("/v1/jobs/estimate", json={**body, "optics": {"pitch_um": 1e-9}}).status_code == 422
        assert c.post("/v1/jobs/estimate", json={**body, "bogus": 1}).status_code == 422
        # the estimate is the one the submit records
        job = c.post("/v1/jobs", json=body)
        assert job.status_code == 202, job.text
        # the same figures; the one-minute load average it reports alongside is read anew and may have moved
        recorded = job.json()["estimate"]
        for est_doc in (recorded, e["estimate"]):
            est_doc.get("load", {}).pop("load_1min", None)
        assert recorded == e["estimate"]
        assert c.delete(f"/v1/jobs/{job.json()['id']}").status_code == 202  # frees the worker for the browser
    with server.client("reader") as c:
        assert c.post("/v1/jobs/estimate", json=body).status_code == 403
    with server.client(None) as c:
        assert c.post("/v1/jobs/estimate", json=body).status_code == 401


def test_pictures_need_a_token_and_a_finished_job(server, scene):
    with server.client("submit") as c:
        job = c.post("/v1/jobs", json={"scene_id": scene["id"], **SMALL_JOB, "frames": 1, "spp": 1}).json()
        c.delete(f"/v1/jobs/{job['id']}")
        assert c.get(f"/v1/jobs/{job['id']}/pictures").status_code == 409
        assert c.get("/v1/jobs/jnope/pictures").status_code == 404
        assert c.get(f"/v1/jobs/{job['id']}/pictures/..%2F..%2Fservice.db").status_code in (404, 422)
        assert c.get(f"/v1/jobs/{job['id']}/pictures/index.json").status_code == 422
    with server.client(None) as c:
        assert c.get(f"/v1/jobs/{job['id']}/pictures").status_code == 401
        assert c.get(f"/v1/jobs/{job['id']}/pictures/sweep-00.png").status_code == 401


# ---- in a browser ---------------------------------------------------------------------------------------------
def _browser():
    webdriver = pytest.importorskip("selenium.webdriver")
    if not (CHROMIUM and CHROMEDRIVER):
        pytest.skip("needs Debian's chromium and chromium-driver (scripts/setup.sh installs them)")
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
                "--window-size=1280,1500", "--disable-extensions", "--no-first-run"):
        opts.add_argument(arg)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=opts)


def _pixels(driver, img_id: str) -> str:
    """A digest of what an <img> shows (drawn on a canvas)."""
    return driver.execute_script("""
        const img = document.getElementById(arguments[0]);
        const c = document.createElement('canvas'); c.width = img.naturalWidth; c.height = img.naturalHeight;
        const g = c.getContext('2d'); g.drawImage(img, 0, 0);
        const d = g.getImageData(0, 0, c.width, c.height).data; let h = 0;
        for (let i = 0; i < d.length; i++) h = (h * 31 + d[i]) >>> 0;
        return c.width + 'x' + c.height + ':' + h;""", img_id)


def _shot(driver, folder: Path, name: str) -> None:
    driver.execute_script("window.scrollTo(0, 0); document.activeElement && document.activeElement.blur()")
    driver.save_screenshot(str(folder / name))


def _shots_dir(tmp: Path) -> Path:
    out = os.environ.get("HOLO_WEB_SCREENSHOTS")
    d = (REPO / out) if out and not os.path.isabs(out) else Path(out) if out else tmp
    d.mkdir(parents=True, exist_ok=True)
    return d


def test_browser_signs_in_submits_follows_and_views_a_job(server, scene, tmp_path):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys
    from selenium.webdriver.support.ui import Select, WebDriverWait

    with server.client("agent") as c:  # a display whose agent reports markup
        assert c.post("/v1/displays/lab-web/heartbeat", json={"agent_version": "test", "state": "showing",
                                                              "showing": {"job_id": "j-first", "frame": 0},
                                                              "message": XSS_MESSAGE}).status_code == 204
    bundle = tmp_path / "scene.zip"
    bundle.write_bytes(scene["zip"])
    shots = _shots_dir(tmp_path)
    driver = _browser()
    try:
        wait = WebDriverWait(driver, 30, poll_frequency=0.1)
        visible = lambda i: driver.find_element(By.ID, i).is_displayed()  # noqa: E731
        # read in one script call: the page re-renders live, so a found element may be replaced before .text
        text = lambda i: driver.execute_script("const e = document.getElementById(arguments[0]); "  # noqa: E731
                                               "return e ? e.innerText.trim() : '';", i)

        driver.get(server.url + "/")
        wait.until(lambda d: visible("signin"))
        _shot(driver, shots, "web-signin.png")
        driver.find_element(By.ID, "token").send_keys("hpt_wrong_token" + Keys.ENTER)
        wait.until(lambda d: "not valid" in text("signin-error"))
        driver.find_element(By.ID, "token").send_keys(server.submit + Keys.ENTER)
        wait.until(lambda d: visible("home") and visible("submit"))
        assert server.submit not in driver.current_url
        assert driver.execute_script("return sessionStorage.getItem('holo.token')") == server.submit
        assert driver.execute_script("return localStorage.length") == 0

        # the display's markup message is text
        wait.until(lambda d: "projector warm" in text("displays"))
        assert XSS_MESSAGE in text("displays")
        assert "j-first frame 1" in text("displays")  # frames count from 1, as on the job page and its frame box

        # upload, see the scene (its name is markup: text), options, estimate, submit
        driver.find_element(By.ID, "bundle").send_keys(str(bundle))
        driver.find_element(By.ID, "entry").send_keys(f"{XSS_FOLDER}/scene.xml")
        driver.find_element(By.ID, "upload-button").click()
        wait.until(lambda d: d.find_elements(By.ID, "scene-entry"))
        assert text("scene-entry") == f"{XSS_FOLDER}/scene.xml"
        Select(driver.find_element(By.ID, "preset")).select_by_value("fast")
        Select(driver.find_element(By.ID, "encoder")).select_by_value("dpac")
        for field, value in (("frames", "2"), ("res-h", "64"), ("res-w", "64"), ("spp", "4"), ("display", "lab-web")):
            box = driver.find_element(By.ID, field)
            box.clear()
            box.send_keys(value)
        wait.until(lambda d: text("estimate").startswith("Estimate:") and
                   d.find_element(By.ID, "submit-button").is_enabled())
        assert "peak memory" in text("estimate") and "4 rays per pixel" in text("estimate")
        limit = driver.find_element(By.ID, "time-limit")  # a render time limit: the estimate says so, then cleared
        limit.send_keys("5")
        wait.until(lambda d: "rays until the time limit" in text("estimate"))
        limit.send_keys(Keys.BACKSPACE)  # typed away (an input event): the estimate follows the empty box
        wait.until(lambda d: "4 rays per pixel" in text("estimate"))
        _shot(driver, shots, "web-submit.png")
        driver.find_element(By.ID, "submit-button").click()

        # the job page follows the job live until it is done
        wait.until(lambda d: re.match(r".*#/jobs/j[0-9a-f]+$", d.current_url))
        job_id = driver.current_url.rsplit("/", 1)[1]
        states, stages = set(), set()

        def done(d):
            states.add(text("job-state"))
            stages.add(text("job-stage"))
            return text("job-state") in ("succeeded", "failed", "cancelled")

        WebDriverWait(driver, 120, poll_frequency=0.1).until(done)
        assert text("job-state") == "succeeded", text("job-error")
        assert {"queued", "running"} & states and len(stages) > 2, (states, stages)  # live progress came in
        job = wait_state(server.client("reader"), job_id, ("succeeded",))
        assert job["display"] == "lab-web" and job["options"]["encoder"] == "dpac"
        assert job["options"]["optics"]["resolution_hw"] == [64, 64] and job["options"]["optics"]["frames"] == 2

        # plan, timings, downloads, estimate vs actual
        assert driver.find_elements(By.CSS_SELECTOR, "#plan li")
        assert "render" in text("timings") and "pictures" in text("timings")
        assert "measured peak" in text("job-facts") and "estimated" in text("job-facts")
        assert {b.get_attribute("data-file") for b in driver.find_elements(By.CSS_SELECTOR, "#job-downloads button")} \
            == {"stack.npz", "frames.zip", "preview.png"}

        # the focal sweep: moving the slider changes the picture
        wait.until(lambda d: (d.find_element(By.ID, "sweep-img").get_attribute("src") or "").startswith("blob:")
                   and len(d.find_elements(By.CSS_SELECTOR, "#grid img")) == 9
                   and d.execute_script("return document.getElementById('sweep-img').complete"))
        slider = driver.find_element(By.ID, "focus")
        assert slider.get_attribute("max") == "8" and slider.get_attribute("value") == "4"
        before_src, before_px, before_label = (driver.find_element(By.ID, "sweep-img").get_attribute("src"),
                                               _pixels(driver, "sweep-img"), text("focus-label"))
        slider.send_keys(Keys.END)
        wait.until(lambda d: d.find_element(By.ID, "sweep-img").get_attribute("data-index") == "8"
                   and d.execute_script("return document.getElementById('sweep-img').complete"))
        assert driver.find_element(By.ID, "sweep-img").get_attribute("src") != before_src
        assert _pixels(driver, "sweep-img") != before_px, "the focus slider changes what the picture shows"
        assert text("focus-label") != before_label and "mm from the SLM" in text("focus-label")
        slider.send_keys(Keys.HOME)
        wait.until(lambda d: d.find_element(By.ID, "sweep-img").get_attribute("data-index") == "0")
        slider.send_keys(Keys.ARROW_RIGHT, Keys.ARROW_RIGHT, Keys.ARROW_RIGHT, Keys.ARROW_RIGHT)
        wait.until(lambda d: d.find_element(By.ID, "sweep-img").get_attribute("data-index") == "4")
        _shot(driver, shots, "web-job.png")

        # the job list: state, scene name as text, estimate vs actual
        driver.get(server.url + "/#/")
        wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, f'tr[data-job-id="{job_id}"]'))
        row = driver.execute_script("return document.querySelector(`tr[data-job-id=\"${arguments[0]}\"]`).innerText",
                                    job_id)
        assert "succeeded" in row and f"{XSS_FOLDER}/scene.xml" in row and "100%" in row
        _shot(driver, shots, "web-home.png")

        # nothing ran: the markup stayed text everywhere
        assert driver.execute_script("return window.__xss") is None
        assert not driver.find_elements(By.CSS_SELECTOR, 'img[src="x"], img[onerror], main script')
        assert "&lt;img src=x onerror=window.__xss=1&gt;" in driver.page_source
        urls = driver.execute_script("return performance.getEntries().map(e => e.name)")
        assert urls and not [u for u in urls if server.submit in u], "the token never goes into a URL"
        csp_errors = [e for e in driver.get_log("browser") if "Content Security Policy" in e.get("message", "")]
        assert not csp_errors, csp_errors

        # a read-only token views the job, and is offered no submit form
        driver.find_element(By.ID, "signout").click()
        wait.until(lambda d: visible("signin"))
        assert driver.execute_script("return sessionStorage.getItem('holo.token')") is None
        driver.find_element(By.ID, "token").send_keys(server.reader + Keys.ENTER)
        wait.until(lambda d: visible("home"))
        assert not visible("submit")
        driver.get(f"{server.url}/#/jobs/{job_id}")
        wait.until(lambda d: (d.find_element(By.ID, "sweep-img").get_attribute("src") or "").startswith("blob:"))
        assert text("job-state") == "succeeded"
    finally:
        driver.quit()


def test_pictures_index_and_pngs(server):
    """The browser test's job: its pictures index (sweep far to near, a 3x3 grid) and PNGs as served."""
    with server.client("reader") as c:
        jobs = [j for j in c.get("/v1/jobs", params={"state": "succeeded"}).json()["jobs"]]
        if not jobs:
            pytest.skip("no finished job (the browser test did not run)")
        jid = jobs[0]["id"]
        idx = c.get(f"/v1/jobs/{jid}/pictures")
        assert idx.status_code == 200, idx.text
        doc = idx.json()
        assert doc["stack_sha256"] == jobs[0]["stack_sha256"] and doc["shape_hw"] == [64, 64]
        sweep, grid = doc["sweep"]["pictures"], doc["grid"]["pictures"]
        assert len(sweep) == 9 and len(grid) == 9
        z = [p["z_mm"] for p in sweep]
        assert z == sorted(z) and z[0] < z[-1]  # far to near: hologram depth grows
        assert grid[4]["offset_mm"] == [0.0, 0.0] and grid[3]["offset_mm"][0] < 0 < grid[5]["offset_mm"][0]
        png = c.get(sweep[0]["url"])
        assert png.status_code == 200 and png.headers["content-type"] == "image/png"
        assert png.content.startswith(b"\x89PNG") and png.headers["etag"] == f'"{sweep[0]["sha256"]}"'
        assert png.headers["x-content-type-options"] == "nosniff"
        assert c.get(sweep[0]["url"], headers={"If-None-Match": png.headers["etag"]}).status_code == 304
        assert c.get(f"/v1/jobs/{jid}/pictures/sweep-99.png").status_code == 404
    from service.auth import create_token
    from service.db import Database

    other = create_token(Database(server.data_dir / "service.db"), scopes=["read"], name="t", owner="lab2")[1]
    with server.client(other) as c:
        assert c.get(f"/v1/jobs/{jid}/pictures").status_code == 404
        assert c.get(f"/v1/jobs/{jid}/pictures/sweep-00.png").status_code == 404
