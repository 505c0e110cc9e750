"""A small HTTP client of the service (used by `holo submit`; handy in scripts): upload a scene folder or zip,
submit a job, follow its events, download and verify its stack."""

from __future__ import annotations

import hashlib
import io
import json
import os
import zipfile
from pathlib import Path
from typing import Any, Callable, Iterator, Optional

import httpx

__all__ = ["ServiceClient", "ClientError", "zip_folder", "iter_sse"]


class ClientError(RuntimeError):
    """The server refused a request or answered something unexpected; the message says what."""


def zip_folder(folder: Path) -> bytes:
    """The folder's regular files in a zip (paths relative to it; symbolic links are not followed out)."""
    buf = io.BytesIO()
    root = folder.resolve()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for dirpath, _, files in os.walk(root):
            for name in sorted(files):
                p = Path(dirpath) / name
                if p.is_file() and p.resolve().is_relative_to(root):
                    zf.write(p, p.relative_to(root).as_posix())
    return buf.getvalue()


def iter_sse(lines: Iterator[str]) -> Iterator[tuple[str, dict]]:
    """(event, data) pairs from server-sent-event lines."""
    event, data = "message", []
    for line in lines:
        if line == "":
            if data:
                try:
                    yield event, json.loads("\n".join(data))
                except ValueError:
                    pass
            event, data = "message", []
        elif line.startswith(":"):
            continue
        elif line.startswith("event:"):
            event = line[6:].strip()
        elif line.startswith("data:"):
            data.append(line[5:].strip())


class ServiceClient:
    def __init__(self, server: str, *, token: Optional[str], timeout_s: float = 30.0) -> None:
        if not server.startswith(("http://", "https://")):
            raise ValueError(f"server must start with http:// or https://, got {server!r}")
        if not timeout_s > 0:
            raise ValueError(f"timeout_s must be > 0, got {timeout_s}")
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.http = httpx.Client(base_url=server.rstrip("/"), headers=headers, timeout=timeout_s)

    def close(self) -> None:
        self.http.close()

    def __enter__(self) -> "ServiceClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @staticmethod
    def _check(resp: httpx.Response, what: str) -> httpx.Response:
        if resp.status_code >= 400:
            try:
                detail = resp.json().get("detail", resp.text)
            except ValueError:
                detail = resp.text[:300]
            raise ClientError(f"{what}: HTTP {resp.status_code}: {detail}")
        return resp

    def upload_scene(self, scene: Path, *, entry: Optional[str] = None) -> dict:
        """Upload a scene folder, zip file, or XML file (its folder is the bundle; its name the entry)."""
        scene = Path(scene)
        if scene.is_file() and scene.suffix.lower() == ".xml":
            entry = entry or scene.name
            scene = scene.parent
        if scene.is_dir():
            payload = zip_folder(scene)
        elif scene.is_file() and scene.suffix.lower() == ".zip":
            payload = scene.read_bytes()
        else:
            raise ClientError(f"scene must be a folder, a .zip or an .xml file: {scene}")
        data = {"entry": entry} if entry else {}
        resp = self.http.post("/v1/scenes", files={"bundle": ("bundle.zip", payload, "application/zip")}, data=data)
        return self._check(resp, "upload").json()

    def submit(self, body: dict[str, Any], *, idempotency_key: Optional[str] = None) -> dict:
        headers = {"Idempotency-Key": idempotency_key} if idempotency_key else {}
        return self._check(self.http.post("/v1/jobs", json=body, headers=headers), "submit").json()

    def estimate(self, body: dict[str, Any]) -> dict:
        """What submitting ``body`` would predict (POST /v1/jobs/estimate: time, memory, quality, warnings)."""
        return self._check(self.http.post("/v1/jobs/estimate", json=body), "estimate").json()

    def job(self, job_id: str) -> dict:
        return self._check(self.http.get(f"/v1/jobs/{job_id}"), "status").json()

    def follow(self, job_id: str, on_event: Callable[[str, dict], None]) -> dict:
        """Stream the job's events to ``on_event`` until it ends; returns the final job."""
        with self.http.stream("GET", f"/v1/jobs/{job_id}/events", timeout=httpx.Timeout(30.0, read=None)) as resp:
            if resp.status_code >= 400:
                resp.read()
                self._check(resp, "events")
            for event, data in iter_sse(resp.iter_lines()):
                on_event(event, data)
        return self.job(job_id)

    def download_stack(self, job_id: str, out: Path) -> str:
        """Download the stack to ``out`` (atomically) and check its sha256 against the ETag; returns it."""
        out = Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_name(f".{out.name}.part")
        h = hashlib.sha256()
        with self.http.stream("GET", f"/v1/jobs/{job_id}/stack") as resp:
            if resp.status_code >= 400:
                resp.read()
                self._check(resp, "download")
            etag = resp.headers.get("ETag", "").strip('"')
            with open(tmp, "wb") as fh:
                for chunk in resp.iter_bytes():
                    h.update(chunk)
                    fh.write(chunk)
        digest = h.hexdigest()
        if etag and etag != digest:
            tmp.unlink(missing_ok=True)
            raise ClientError(f"download: bytes hash to {digest}, the server's ETag says {etag}")
        os.replace(tmp, out)
        return digest
