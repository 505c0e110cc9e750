"""A small, real HTTP server implementing the display-facing endpoints of the service contract, for the
display agent's tests (a separate process, restartable, with switches to misbehave).

    python tests/agent/stack_server.py --state DIR --port 0 --token T

DIR holds ``jobs.json`` (a list of job objects, newest first; "id", "display", "state", "created_at",
"finished_at") and ``<id>.npz`` stacks; ``control.json`` (re-read on every request) switches behaviour:
``{"mode": "normal" | "truncate" | "corrupt" | "slow" | "error500", "count": N, "rate_bps": B}`` -- the mode
applies to the next N stack downloads (default: all) after the control file last changed; "slow" sends
``rate_bps`` bytes per second. Every request and heartbeat is appended to ``DIR/server.log`` (JSON lines).
The port actually bound is written to ``DIR/port``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, urlparse

_LOCK = threading.Lock()
_CONTROL = {"key": None, "served": 0}


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


class Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    state: Path
    token: str

    def log_message(self, fmt: str, *args: object) -> None:  # quiet stderr
        pass

    def _log(self, **rec: object) -> None:
        rec["t"] = time.time()
        with _LOCK, open(self.state / "server.log", "a") as fh:
            fh.write(json.dumps(rec) + "\n")

    def _json(self, code: int, obj: object) -> None:
        body = json.dumps(obj).encode()
        self.send_response(code)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def _auth(self) -> bool:
        if self.headers.get("Authorization") != f"Bearer {self.token}":
            self._json(401, {"detail": "missing or bad token"})
            return False
        return True

    def _jobs(self) -> list[dict]:
        try:
            jobs = json.loads((self.state / "jobs.json").read_text())
        except (OSError, json.JSONDecodeError):
            return []
        for j in jobs:
            f = self.state / f"{j['id']}.npz"
            j.setdefault("stack_sha256", _sha(f) if f.is_file() and j.get("state") == "succeeded" else None)
        return jobs

    def _control(self) -> dict:
        try:
            text = (self.state / "control.json").read_text()
            ctl = json.loads(text)
        except (OSError, json.JSONDecodeError):
            text, ctl = "", {}
        with _LOCK:
            if _CONTROL["key"] != text:
                _CONTROL["key"], _CONTROL["served"] = text, 0
            count = ctl.get("count")
            active = count is None or _CONTROL["served"] < int(count)
            _CONTROL["served"] += 1
        return ctl if active else {}

    def do_GET(self) -> None:  # noqa: N802
        url = urlparse(self.path)
        if not self._auth():
            self._log(method="GET", path=url.path, status=401)
            return
        if url.path == "/v1/jobs":
            q = parse_qs(url.query)
            jobs = self._jobs()
            if "display" in q:
                jobs = [j for j in jobs if j.get("display") == q["display"][0]]
            if "state" in q:
                jobs = [j for j in jobs if j.get("state") == q["state"][0]]
            jobs = jobs[: int(q.get("limit", ["50"])[0])]
            self._log(method="GET", path=url.path, status=200, n=len(jobs))
            return self._json(200, {"jobs": jobs})
        if url.path == "/v1/displays":
            return self._json(200, {"displays": []})
        m = re.fullmatch(r"/v1/jobs/([A-Za-z0-9_.-]+)(/stack|/events)?", url.path)
        job = next((j for j in self._jobs() if m and j["id"] == m.group(1)), None)
        if job is None:
            self._log(method="GET", path=url.path, status=404)
            return self._json(404, {"detail": "no such job"})
        if m.group(2) is None:
            return self._json(200, job)
        if m.group(2) == "/events":
            body = f"event: state\ndata: {json.dumps({'state': job['state']})}\n\n".encode()
            self.send_response(200)
            self.send_header("Content-Type", "text/event-stream")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)
            return
        self._stack(job, url.path)

    def _stack(self, job: dict, path: str) -> None:
        f = self.state / f"{job['id']}.npz"
        if not f.is_file():
            return self._json(404, {"detail": "no stack"})
        data = f.read_bytes()
        digest = hashlib.sha256(data).hexdigest()
        etag = f'"{digest}"'
        if self.headers.get("If-None-Match") == etag:
            self._log(method="GET", path=path, status=304)  # logged before the client can see the reply
            self.send_response(304)
            self.send_header("ETag", etag)
            self.end_headers()
            return
        ctl = self._control()
        mode = ctl.get("mode", "normal")
        if mode == "error500":
            self._log(method="GET", path=path, status=500, mode=mode)
            return self._json(500, {"detail": "injected failure"})
        start, status = 0, 200
        rng = self.headers.get("Range")
        if_range = self.headers.get("If-Range")
        if rng and (if_range is None or if_range == etag):
            m = re.fullmatch(r"bytes=(\d+)-", rng)
            if not m or int(m.group(1)) >= len(data):
                self._log(method="GET", path=path, status=416, range=rng)
                self.send_response(416)
                self.send_header("Content-Range", f"bytes */{len(data)}")
                self.send_header("Content-Length", "0")
                self.end_headers()
                return
            start, status = int(m.group(1)), 206
        body = bytearray(data[start:])
        if mode == "corrupt":
            body[len(body) // 2] ^= 0xFF
        self.send_response(status)
        self.send_header("Content-Type", "application/octet-stream")
        self.send_header("Content-Length", str(len(body)))
        self.send_header("ETag", etag)
        self.send_header("X-Content-SHA256", digest)
        self.send_header("Accept-Ranges", "bytes")
        if status == 206:
            self.send_header("Content-Range", f"bytes {start}-{len(data) - 1}/{len(data)}")
        self._log(method="GET", path=path, status=status, mode=mode, range=rng, start=start)
        self.end_headers()
        if mode == "truncate":
            self.wfile.write(bytes(body[: len(body) // 2]))
            self.wfile.flush()
            self.close_connection = True
            return
        if mode == "slow":
            rate = max(1, int(ctl.get("rate_bps", 100_000)))
            step = max(1, rate // 20)
            for i in range(0, len(body), step):
                self.wfile.write(bytes(body[i:i + step]))
                self.wfile.flush()
                time.sleep(step / rate)
            return
        self.wfile.write(bytes(body))

    def do_POST(self) -> None:  # noqa: N802
        url = urlparse(self.path)
        length = int(self.headers.get("Content-Length", "0"))
        raw = self.rfile.read(length) if length else b""
        if not self._auth():
            return
        m = re.fullmatch(r"/v1/displays/([A-Za-z0-9_.-]+)/heartbeat", url.path)
        if not m:
            return self._json(404, {"detail": "not found"})
        try:
            body = json.loads(raw)
        except json.JSONDecodeError:
            return self._json(422, {"detail": "bad json"})
        self._log(method="POST", path=url.path, status=204, heartbeat=body, display=m.group(1))
        self.send_response(204)
        self.end_headers()


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--state", type=Path, required=True)
    ap.add_argument("--port", type=int, default=0)
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--token", required=True)
    args = ap.parse_args(argv)
    Handler.state = args.state
    Handler.token = args.token
    ThreadingHTTPServer.allow_reuse_address = True
    srv = ThreadingHTTPServer((args.host, args.port), Handler)
    srv.daemon_threads = True
    (args.state / "port.tmp").write_text(str(srv.server_address[1]))
    (args.state / "port.tmp").replace(args.state / "port")
    print(f"listening {args.host}:{srv.server_address[1]}", flush=True)
    try:
        srv.serve_forever(poll_interval=0.1)
    except KeyboardInterrupt:
        pass
    finally:
        srv.server_close()
    sys.exit(0)


if __name__ == "__main__":
    main()
