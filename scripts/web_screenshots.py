"""Screenshots of the results page for the README and docs/web.md, made as a person uses it: a real `holo serve`,
the project's own mirror scene (holocore.scene.paper), uploaded and submitted from headless Chromium at a size
where the hologram is recognisable, re-run with changes, and compared side by side.

    .venv/bin/python scripts/web_screenshots.py --out docs/screenshots [--resolution 540x960 --frames 8]

Writes web-home.png (the list, the queue, the form with the scene and the estimate), web-job-running.png (the
job's page while it runs: its plan, step timeline, worker and log tail), web-job.png (a finished job's page),
web-compare.png (two jobs side by side), web-sweep.png (a frames sweep of the same scene, 1 to 24 frames at a
quarter of the size: its jobs and the chart of predicted quality and estimated and actual time against frames; a
quarter of the paper's display is below the size its views can be scored at, so the sweep is not evaluated) and
web-signin.png. Needs Debian's chromium and chromium-driver
(scripts/setup.sh installs them). Takes about half an hour on 2 cores (two renders and encodes, the sweep's five
jobs); at 540x960 the
hologram shows 8.8 degrees of the camera's 17.5: the mirror, its checker frame and the poster seen in it.
"""

from __future__ import annotations

import argparse
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import httpx

REPO = Path(__file__).resolve().parents[1]


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _browser(width: int, height: int):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver = shutil.which("chromedriver")
    if not (chromium and driver):
        sys.exit("error: needs Debian's chromium and chromium-driver (scripts/setup.sh installs them)")
    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu", "--hide-scrollbars",
                f"--window-size={width},{height}", "--disable-extensions", "--no-first-run"):
        opts.add_argument(arg)
    return webdriver.Chrome(service=Service(executable_path=driver), options=opts)


class Shots:
    def __init__(self, driver, out: Path, width: int) -> None:
        from selenium.webdriver.support.ui import WebDriverWait

        self.d, self.out, self.width = driver, out, width
        self.wait = lambda pred, t=600: WebDriverWait(driver, t, poll_frequency=0.25).until(lambda d: pred())

    def js(self, script: str, *args):
        return self.d.execute_script(script, *args)

    def has(self, id_: str) -> bool:
        return bool(self.js("const e = document.getElementById(arguments[0]);"
                            "return !!e && e.getClientRects().length > 0 && !e.closest('[hidden]')", id_))

    def set(self, id_: str, value: str) -> None:
        from selenium.webdriver.common.by import By
        from selenium.webdriver.common.keys import Keys

        box = self.d.find_element(By.ID, id_)
        box.send_keys(Keys.CONTROL, "a")
        box.send_keys(Keys.DELETE)
        box.send_keys(value)

    def choose(self, id_: str, value: str) -> None:
        from selenium.webdriver.common.by import By
        from selenium.webdriver.support.ui import Select

        Select(self.d.find_element(By.ID, id_)).select_by_value(value)

    def click(self, id_: str) -> None:
        self.js("document.getElementById(arguments[0]).click()", id_)

    def snap(self, name: str) -> None:
        """The whole page (the window grown to the document's height), then the window put back."""
        time.sleep(0.5)  # the last pictures decoded
        # the window's height less its viewport's (headless Chromium keeps some): the page's foot is in the shot
        h = int(self.js("return Math.ceil(document.documentElement.scrollHeight)"
                        " + Math.max(0, window.outerHeight - window.innerHeight)"))
        self.d.set_window_size(self.width, min(max(h, 600), 4000))
        time.sleep(0.3)
        self.d.save_screenshot(str(self.out / name))
        from PIL import Image  # 256 colours: a third of the bytes, the holograms' speckle still as it is

        Image.open(self.out / name).convert("RGB").quantize(
            colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(self.out / name, optimize=True)
        self.d.set_window_size(self.width, 1000)
        print(f"wrote {self.out / name}", file=sys.stderr)


def _options(s: Shots, res_hw: tuple[int, int], frames: int, preset: str) -> None:
    s.choose("preset", preset)
    s.set("res-h", str(res_hw[0]))
    s.set("res-w", str(res_hw[1]))
    s.set("frames", str(frames))
    if s.has("evaluate") and not s.js("return document.getElementById('evaluate').checked"):
        s.click("evaluate")  # ground truth beside the hologram, where the page offers it


def _submit(s: Shots) -> str:
    s.wait(lambda: s.js("return !document.getElementById('submit-button').disabled"))
    s.click("submit-button")
    s.wait(lambda: s.js("return location.hash").startswith("#/jobs/"), 60)
    return s.js("return location.hash").split("/")[-1]


def _finished(s: Shots) -> None:
    s.wait(lambda: s.js("const e = document.getElementById('job-state'); return !!e && "
                        "['succeeded', 'failed', 'cancelled'].includes(e.innerText.trim())"))
    state = s.js("return document.getElementById('job-state').innerText.trim()")
    if state != "succeeded":
        why = s.js("return document.getElementById('job-error').innerText")
        sys.exit(f"error: the job {state}: {why}")
    s.wait(lambda: s.js("const i = document.getElementById('sweep-img'); return !!i.src && i.complete"), 120)
    if s.has("evaluation"):  # the ground truth beside the hologram
        s.wait(lambda: s.js("const i = document.getElementById('eval-truth'); return !!i.src && i.complete"), 120)


SWEEP_FRAMES = "1, 2, 4, 8, 24"


def _sweep(s: Shots, url: str, bundle: Path, res_hw: tuple[int, int]) -> None:
    """A frames sweep from the form and its page once every job has finished (and, where the jobs could be
    evaluated, shows its measured quality)."""
    s.d.get(url + "/#/")
    s.d.find_element("id", "bundle").send_keys(str(bundle))
    s.click("upload-button")
    s.wait(lambda: s.has("job-form"), 120)
    _options(s, res_hw, 1, "fast")
    s.choose("sweep-option", "frames")
    s.set("sweep-values", SWEEP_FRAMES)
    s.wait(lambda: s.js("const b = document.getElementById('submit-button');"
                        "return !b.disabled && b.innerText.startsWith('Submit sweep')"), 120)
    s.click("submit-button")
    s.wait(lambda: s.js("return location.hash").startswith("#/sweeps/"), 60)
    n = len(SWEEP_FRAMES.split(","))
    s.wait(lambda: s.js("return document.querySelectorAll('#sweep-jobs tr[data-state=succeeded]').length") == n, 3600)
    measured = "return document.querySelectorAll('#sweep-quality circle[data-series=measured]').length"
    s.d.refresh()  # the page stops following a sweep whose jobs are all final: the last evaluation is read anew
    try:
        s.wait(lambda: s.js(measured) == n, 120)
    except Exception:  # the picture is still worth having; say what it lacks
        print(f"warning: {s.js(measured)} of {n} jobs show a measured quality", file=sys.stderr)
    s.snap("web-sweep.png")


def _home(s: Shots, url: str, bundle: Path, res_hw: tuple[int, int], args) -> None:
    """The list with its finished jobs' thumbnails, and the form with the scene and its estimate."""
    s.d.get(url + "/#/")
    s.wait(lambda: s.js("return document.querySelectorAll('#jobs tbody tr img.thumb').length") >= 2, 60)
    s.d.find_element("id", "bundle").send_keys(str(bundle))
    s.click("upload-button")
    s.wait(lambda: s.has("job-form"), 120)
    _options(s, res_hw, args.frames, args.preset)
    s.wait(lambda: "Estimate:" in s.js("return document.getElementById('estimate').innerText"), 60)
    s.snap("web-home.png")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=REPO / "docs" / "screenshots")
    ap.add_argument("--resolution", default="540x960", help="the jobs' SLM size, rows x columns")
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--preset", default="balanced", choices=("fast", "balanced", "reference"))
    ap.add_argument("--width", type=int, default=1440, help="the browser window's width, px")
    ap.add_argument("--sweep-only", action="store_true",
                    help="only web-sweep.png and web-home.png (the frames sweep and the list it leaves, 10 minutes)")
    ap.add_argument("--running-only", action="store_true",
                    help="stop after web-job-running.png (and web-signin.png): the first job's render, not ten minutes")
    args = ap.parse_args(argv)
    res_hw = tuple(int(v) for v in args.resolution.lower().split("x"))
    args.out.mkdir(parents=True, exist_ok=True)

    from holocore.scene.paper import write_paper_scene
    from service.auth import create_token
    from service.db import Database

    with tempfile.TemporaryDirectory(prefix="holo-shots-") as tmp_s:
        tmp = Path(tmp_s)
        data = tmp / "data"
        data.mkdir()
        submit = create_token(Database(data / "service.db"), scopes=("submit", "read"), name="lab")[1]
        agent = create_token(Database(data / "service.db"), scopes=("agent",), name="lab-agent")[1]
        write_paper_scene("mirror", tmp / "scene")
        bundle = tmp / "mirror-room.zip"
        with zipfile.ZipFile(bundle, "w", zipfile.ZIP_DEFLATED) as zf:
            for p in sorted((tmp / "scene").rglob("*")):
                if p.is_file():
                    zf.write(p, p.relative_to(tmp / "scene").as_posix())
        port = _port()
        url = f"http://127.0.0.1:{port}"
        env = dict(os.environ, PYTHONPATH=str(REPO))
        env.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")
        log = open(tmp / "server.log", "wb")
        server = subprocess.Popen([sys.executable, "-m", "holo", "serve", "--data-dir", str(data), "--port", str(port),
                                   "--workers", "1"], stdout=log, stderr=subprocess.STDOUT, env=env, cwd=REPO)
        driver = None
        try:
            for _ in range(300):
                try:
                    if httpx.get(f"{url}/readyz", timeout=1).status_code == 200:
                        break
                except httpx.HTTPError:
                    pass
                time.sleep(0.1)
            httpx.post(f"{url}/v1/displays/lab-1/heartbeat", headers={"Authorization": f"Bearer {agent}"},
                       json={"agent_version": "sim", "state": "idle", "message": "simulated SLM"})
            driver = _browser(args.width, 1000)
            s = Shots(driver, args.out, args.width)
            driver.get(url + "/")
            s.wait(lambda: s.has("signin"))
            s.snap("web-signin.png")
            s.set("token", submit)
            s.click("signin-button")
            s.wait(lambda: s.has("home"))
            if args.sweep_only:
                _sweep(s, url, bundle, (res_hw[0] // 2, res_hw[1] // 2))
                _home(s, url, bundle, res_hw, args)
                return 0
            driver.find_element("id", "bundle").send_keys(str(bundle))
            s.click("upload-button")
            s.wait(lambda: s.has("job-form"), 120)
            _options(s, res_hw, args.frames, args.preset)
            s.set("display", "lab-1")
            first = _submit(s)
            # the job as it runs: its render's plan, the step timeline at encode, the worker, the log's tail
            s.wait(lambda: s.js("const e = document.querySelector('#steps li.current');"
                                "const log = document.getElementById('log-text');"
                                "return !!e && e.dataset.step !== 'render' && !!document.getElementById("
                                "'job-worker').innerText && log.dataset.live === '1' && log.innerText.split("
                                "'\\n').length >= 3"), 1200)
            s.snap("web-job-running.png")
            if args.running_only:
                return 0
            _finished(s)
            s.snap("web-job.png")
            # re-run with changes: half the frames (more speckle), no evaluation
            s.click("job-rerun")
            s.wait(lambda: s.has("rerun-note"), 60)
            s.set("frames", str(max(1, args.frames // 2)))
            if s.js("return document.getElementById('evaluate').checked"):
                s.click("evaluate")
            second = _submit(s)
            _finished(s)
            driver.get(f"{url}/#/compare/{first}/{second}")
            s.wait(lambda: s.js("return ['a', 'b'].every(k => { const i = document.getElementById('cmp-img-' + k);"
                                "return !!i.src && i.complete; })"), 120)
            s.snap("web-compare.png")
            _sweep(s, url, bundle, (res_hw[0] // 2, res_hw[1] // 2))
            _home(s, url, bundle, res_hw, args)
        finally:
            if driver is not None:
                driver.quit()
            server.terminate()
            server.wait(timeout=30)
            log.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
