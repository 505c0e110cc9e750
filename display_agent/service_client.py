"""HTTP client for the service's display API (the contract in docs/display_agent.md).

Downloads are resumable and verified: bytes stream into ``partial/<job>.part`` (``Range`` + ``If-Range``
resume after an interruption), the whole file's sha256 must equal the ETag, ``X-Content-SHA256`` and the job's
``stack_sha256`` (each when present), and the file must open as a consistent stack; only then is it moved into
the cache. ``If-None-Match`` with the cached ETag turns a re-download into a 304.
"""

from __future__ import annotations

import dataclasses
import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import httpx

from display_agent.cache import StackCache, safe_job_id
from holocore.formats import Stack, StackError, file_sha256, open_stack

__all__ = ["ServiceError", "TransientError", "CorruptDownload", "BadStack", "ServiceClient", "FetchResult"]

log = logging.getLogger("holo.agent.http")

_HEX64 = re.compile(r"^[0-9a-f]{64}$")


class ServiceError(RuntimeError):
    """The service refused the request (4xx other than 304/416): not retried quickly."""


class TransientError(RuntimeError):
    """Server unreachable, 5xx, or an interrupted transfer: retry with backoff."""


class CorruptDownload(TransientError):
    """The downloaded bytes do not match the announced hash (dropped; retried)."""


class BadStack(ServiceError):
    """The announced, hash-consistent file is not a valid stack: the job is marked bad, never shown."""


@dataclass(frozen=True)
class FetchResult:
    stack: Stack
    downloaded: bool  # False: served from cache (304 or cache hit)
    resumed_from: int = 0  # bytes already there when the download resumed


def _etag_hex(value: Optional[str]) -> Optional[str]:
    if not value:
        return None
    v = value.strip()
    if v.startswith("W/"):
        v = v[2:]
    v = v.strip('"').lower()
    return v if _HEX64.match(v) else None


class ServiceClient:
    def __init__(self, base_url: str, *, token: Optional[str], timeout_s: float = 10.0,
                 agent_version: str = "0") -> None:
        if not base_url.startswith(("http://", "https://")):
            raise ValueError(f"server url must start with http:// or https://, got {base_url!r}")
        if not (timeout_s > 0):
            raise ValueError(f"timeout_s must be > 0 seconds, got {timeout_s}")
        headers = {"User-Agent": f"holo-display-agent/{agent_version}"}
        if token:
            headers["Authorization"] = f"Bearer {token}"
        self.agent_version = agent_version
        self._http = httpx.Client(base_url=base_url.rstrip("/"), headers=headers,
                                  timeout=httpx.Timeout(timeout_s), follow_redirects=False)

    def close(self) -> None:
        self._http.close()

    def _request(self, method: str, url: str, **kw: Any) -> httpx.Response:
        try:
            resp = self._http.request(method, url, **kw)
        except httpx.TransportError as exc:
            raise TransientError(f"{method} {url}: {type(exc).__name__}: {exc or 'connection failed'}") from exc
        self._raise_for(resp, method, url)
        return resp

    @staticmethod
    def _raise_for(resp: httpx.Response, method: str, url: str) -> None:
        if resp.status_code >= 500 or resp.status_code == 429:
            raise TransientError(f"{method} {url}: HTTP {resp.status_code}")
        if resp.status_code >= 400 and resp.status_code != 416:
            detail = resp.text[:200] if not resp.is_stream_consumed or resp.is_closed else ""
            raise ServiceError(f"{method} {url}: HTTP {resp.status_code} {detail}".strip())

    # API ----------------------------------------------------------------------------------------------------
    def list_jobs(self, display: str, *, state: str = "succeeded", limit: int = 5) -> list[dict]:
        """Jobs for ``display`` in ``state``, the most recently sent to it first (the one it shows next)."""
        resp = self._request("GET", "/v1/jobs", params={"display": display, "state": state, "limit": limit})
        try:
            jobs = resp.json()["jobs"]
        except (ValueError, KeyError, TypeError) as exc:
            raise TransientError(f"GET /v1/jobs: unexpected body: {exc}") from exc
        if not isinstance(jobs, list):
            raise TransientError("GET /v1/jobs: 'jobs' is not a list")
        return [j for j in jobs if isinstance(j, dict) and isinstance(j.get("id"), str)]

    def heartbeat(self, display: str, *, showing: Optional[dict], state: str, message: str) -> None:
        self._request("POST", f"/v1/displays/{display}/heartbeat",
                      json={"agent_version": self.agent_version, "showing": showing, "state": state,
                            "message": message[:500]})

    def fetch_stack(self, job_id: str, cache: StackCache, *, expected_sha256: Optional[str] = None) -> FetchResult:
        """The job's verified stack, from the cache when the server says 304, else downloaded (resuming a
        partial file), verified and installed. Raises TransientError/CorruptDownload (retry later),
        BadStack (never show this file) or ServiceError."""
        safe_job_id(job_id)
        expected = expected_sha256.lower() if expected_sha256 else None
        entry = cache.lookup(job_id)
        if entry is not None and (expected is None or entry.sha256 == expected):
            try:
                stack = cache.open(job_id)
            except StackError as exc:
                log.warning("cached stack of job %s is damaged (%s): removed, downloading again", job_id, exc)
                stack = None
                entry = None
        else:
            stack = None
        part = cache.partial_path(job_id)
        part_etag = part.with_suffix(".etag")
        headers: dict[str, str] = {}
        if stack is not None and entry is not None and entry.etag:
            headers["If-None-Match"] = entry.etag
        have = part.stat().st_size if part.is_file() else 0
        prev_etag = part_etag.read_text().strip() if (have and part_etag.is_file()) else ""
        if have and prev_etag:
            headers["Range"] = f"bytes={have}-"
            headers["If-Range"] = prev_etag
        elif have:
            part.unlink()
            have = 0
        url = f"/v1/jobs/{job_id}/stack"
        try:
            with self._http.stream("GET", url, headers=headers) as resp:
                if resp.status_code == 304 and stack is not None:
                    return FetchResult(stack=stack, downloaded=False)
                if resp.status_code == 416:  # our partial is longer than the file: start over
                    part.unlink(missing_ok=True)
                    part_etag.unlink(missing_ok=True)
                    raise TransientError(f"GET {url}: range not satisfiable; restarting the download")
                if resp.status_code >= 400:
                    resp.read()
                self._raise_for(resp, "GET", url)
                if resp.status_code not in (200, 206):
                    raise TransientError(f"GET {url}: unexpected HTTP {resp.status_code}")
                etag = resp.headers.get("ETag", "")
                header_sha = resp.headers.get("X-Content-SHA256", "").strip().lower() or None
                resumed_from = 0
                mode = "wb"
                if resp.status_code == 206:
                    m = re.match(r"bytes (\d+)-(\d+)/(\d+|\*)", resp.headers.get("Content-Range", ""))
                    if not m or int(m.group(1)) != have:
                        part.unlink(missing_ok=True)
                        raise TransientError(f"GET {url}: bad Content-Range {resp.headers.get('Content-Range')!r}")
                    mode, resumed_from = "ab", have
                    log.info("resuming download of job %s at byte %d", job_id, have)
                part_etag.write_text(etag)
                with open(part, mode) as fh:
                    for chunk in resp.iter_bytes():
                        fh.write(chunk)
        except httpx.TransportError as exc:
            size = part.stat().st_size if part.is_file() else 0
            raise TransientError(f"download of job {job_id} interrupted at {size} bytes: "
                                 f"{type(exc).__name__}: {exc or 'connection closed'}") from exc
        return self._verify_and_install(job_id, cache, part, part_etag, etag=etag, header_sha=header_sha,
                                        expected=expected, resumed_from=resumed_from)

    def _verify_and_install(self, job_id: str, cache: StackCache, part: Path, part_etag: Path, *, etag: str,
                            header_sha: Optional[str], expected: Optional[str], resumed_from: int) -> FetchResult:
        digest = file_sha256(part)
        claims = {"ETag": _etag_hex(etag), "X-Content-SHA256": header_sha, "job stack_sha256": expected}
        claims = {k: v for k, v in claims.items() if v}
        if not claims:
            part.unlink(missing_ok=True)
            part_etag.unlink(missing_ok=True)
            raise CorruptDownload(f"job {job_id}: the server sent no content hash (ETag/X-Content-SHA256); "
                                  "refusing an unverifiable stack")
        bad = {k: v for k, v in claims.items() if v != digest}
        if bad:
            part.unlink(missing_ok=True)
            part_etag.unlink(missing_ok=True)
            raise CorruptDownload(f"job {job_id}: downloaded bytes hash to {digest[:16]}.. but "
                                  + ", ".join(f"{k} says {v[:16]}.." for k, v in bad.items())
                                  + "; dropped the download")
        try:
            stack = open_stack(part, expected_sha256=digest)
        except StackError as exc:
            part.unlink(missing_ok=True)
            part_etag.unlink(missing_ok=True)
            raise BadStack(f"job {job_id}: {exc}") from exc
        part_etag.unlink(missing_ok=True)
        entry = cache.install(job_id, part, sha256=digest, etag=etag or f'"{digest}"')
        return FetchResult(stack=dataclasses.replace(stack, path=entry.path), downloaded=True,
                           resumed_from=resumed_from)
