"""The display agent daemon: follow the service, keep a verified cache, play on the SLM, report back.

Two threads. The sync thread polls ``GET /v1/jobs?display=NAME&state=succeeded`` (the most recently sent to
the display first: submitted for it, or sent with ``POST /v1/jobs/{id}/display``), fetches the first usable
stack (304/cache or a resumable, hash-checked download), hands it over once it is verified, and posts
heartbeats; failures back off exponentially with jitter, capped, and are logged with what happened. The main
thread owns the SLM (windowing systems want that): it maps phase to gray levels, preloads, and plays by the
policy. A stack reaches the SLM only after every check passed, so nothing partial or corrupt is shown.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Optional

from display_agent import __version__
from display_agent.backoff import Backoff
from display_agent.cache import StackCache
from display_agent.capture import run_capture
from display_agent.config import AgentConfig
from display_agent.focus.client import FocusController, FocusError
from display_agent.hooks import HookError, make_hook
from display_agent.phasemap import PhaseMapping
from display_agent.playback import Player
from display_agent.service_client import (
    BadStack,
    CorruptDownload,
    ServiceClient,
    ServiceError,
    TransientError,
)
from display_agent.slm.base import SLM
from display_agent.slm.drivers import open_slm
from holocore.formats import Stack

__all__ = ["Agent"]

log = logging.getLogger("holo.agent")


@dataclass(frozen=True)
class _Offer:
    job_id: str
    stack: Stack


class Agent:
    """One display's agent. ``run(stop)`` blocks until ``stop`` is set (or ``max_seconds`` pass)."""

    def __init__(self, cfg: AgentConfig, *, slm: Optional[SLM] = None) -> None:
        if not cfg.server_url:
            raise ValueError("server_url is required for the daemon (--server or HOLO_AGENT_SERVER_URL)")
        self.cfg = cfg
        self.mapping = PhaseMapping.from_options(lut=cfg.lut, levels_per_2pi=cfg.levels_per_2pi)
        self.cache = StackCache(cfg.cache_dir, max_stacks=cfg.cache_max_stacks)
        self.client = ServiceClient(cfg.server_url, token=cfg.resolved_token(), timeout_s=cfg.request_timeout_s,
                                    agent_version=__version__)
        self.slm = slm if slm is not None else open_slm(cfg.slm)
        laser = make_hook(cfg.laser_hook, timeout_s=cfg.hook_timeout_s) if cfg.laser_hook else None
        self._wavelengths_nm: list[float] = []
        self.player = Player(self.slm, rate_hz=cfg.rate_hz,
                             laser_hook=None if laser is None else (lambda c: laser(
                                 color=c, wavelength_nm=self._wavelengths_nm[c] if c < len(self._wavelengths_nm)
                                 else "")))
        self.trigger = make_hook(cfg.trigger, timeout_s=cfg.hook_timeout_s) if cfg.trigger else None
        self.focus = (FocusController(cfg.focus_url, baudrate=cfg.baudrate, reply_timeout_s=cfg.focus_reply_timeout_s,
                                      ready_timeout_s=cfg.focus_ready_timeout_s,
                                      reconnect_timeout_s=cfg.focus_reconnect_timeout_s)
                      if cfg.focus_url else None)
        self._lock = threading.Lock()
        self._offer: Optional[_Offer] = None
        self._wanted: Optional[tuple[str, str]] = None  # (job, sha) fetched most recently
        self._bad: set[tuple[str, Optional[str]]] = set()
        self._showing: Optional[str] = None
        self._state = "starting"
        self._message = "starting"

    # status -------------------------------------------------------------------------------------------------
    def _note(self, state: Optional[str] = None, message: Optional[str] = None) -> None:
        with self._lock:
            if state is not None:
                self._state = state
            if message is not None:
                self._message = message

    def _heartbeat(self) -> None:
        with self._lock:
            showing = None
            if self._showing is not None:
                showing = {"job_id": self._showing, "frame": int(self.player.last_frame or 0)}
            state, message = self._state, self._message
        self.client.heartbeat(self.cfg.display, showing=showing, state=state, message=message)

    # sync thread --------------------------------------------------------------------------------------------
    def _sync_once(self) -> None:
        jobs = self.client.list_jobs(self.cfg.display, state="succeeded", limit=5)
        for job in jobs:
            jid, sha = job["id"], job.get("stack_sha256") or None
            if (jid, sha) in self._bad:
                continue
            with self._lock:
                wanted = self._wanted
            if wanted is not None and wanted[0] == jid and (sha is None or sha == wanted[1]):
                return  # already have it (showing, or handed to the player)
            try:
                res = self.client.fetch_stack(jid, self.cache, expected_sha256=sha)
            except BadStack as exc:
                self._bad.add((jid, sha))
                log.error("%s; job %s will not be shown", exc, jid)
                self._note(message=f"refused job {jid}: {exc}")
                continue
            how = (f"downloaded (resumed at byte {res.resumed_from})" if res.resumed_from
                   else "downloaded" if res.downloaded else "from cache")
            log.info("job %s: stack %s, shape %s, sha256 %s..", jid, how, list(res.stack.shape),
                     res.stack.sha256[:16])
            with self._lock:
                self._offer = _Offer(job_id=jid, stack=res.stack)
                self._wanted = (jid, res.stack.sha256)
            return
        if not jobs:
            self._note(message=f"no finished stacks for display {self.cfg.display}")

    def _sync_loop(self, stop: threading.Event) -> None:
        backoff = Backoff(base_s=self.cfg.backoff_base_s, cap_s=self.cfg.backoff_cap_s, jitter=self.cfg.backoff_jitter)
        next_sync = next_hb = time.monotonic()
        outage_since: Optional[float] = None
        unreachable = False  # an outage, rather than only damaged downloads
        while not stop.is_set():
            now = time.monotonic()
            if now >= next_sync:
                try:
                    self._sync_once()
                    if outage_since is not None:
                        log.info("%s after %d failed attempts (%.1f s)",
                                 "service reachable again" if unreachable else "sync recovered", backoff.failures,
                                 time.monotonic() - outage_since)
                        outage_since, unreachable = None, False
                    backoff.reset()
                    next_sync = time.monotonic() + self.cfg.poll_interval_s
                except (TransientError, ServiceError) as exc:
                    outage_since = outage_since or time.monotonic()
                    unreachable = unreachable or not isinstance(exc, CorruptDownload)
                    delay = backoff.next_delay()
                    if isinstance(exc, ServiceError):
                        delay = max(delay, self.cfg.poll_interval_s)
                    log.warning("%s; retry %d in %.2f s", exc, backoff.failures, delay)
                    self._note(message=f"{exc}"[:300])
                    next_sync = time.monotonic() + delay
                except Exception:  # noqa: BLE001 - keep the daemon alive, say what happened
                    log.exception("unexpected error while syncing with the service")
                    next_sync = time.monotonic() + backoff.next_delay()
            if time.monotonic() >= next_hb:
                try:
                    self._heartbeat()
                except (TransientError, ServiceError) as exc:
                    log.debug("heartbeat failed: %s", exc)
                next_hb = time.monotonic() + self.cfg.heartbeat_interval_s
            stop.wait(max(0.0, min(next_sync, next_hb) - time.monotonic()))

    # main thread --------------------------------------------------------------------------------------------
    def _take_offer(self) -> Optional[_Offer]:
        with self._lock:
            offer, self._offer = self._offer, None
            return offer

    def _load(self, offer: _Offer) -> bool:
        try:
            levels = self.mapping.levels(offer.stack.phase, wavelengths_m=offer.stack.wavelengths_m)
            self.slm.load(stack_id=offer.job_id, levels=levels)
        except ValueError as exc:
            log.error("job %s cannot be shown: %s", offer.job_id, exc)
            self._bad.add((offer.job_id, offer.stack.sha256))
            self._note(message=f"cannot show job {offer.job_id}: {exc}")
            return False
        self._wavelengths_nm = [round(w * 1e9, 2) for w in offer.stack.wavelengths_m]
        with self._lock:
            self._showing = offer.job_id
        f, c, h, w = offer.stack.shape
        log.info("showing job %s: %d frames x %d colours, %dx%d, mapping %s, %.1f Hz", offer.job_id, f, c, w, h,
                 self.mapping.source, self.cfg.rate_hz)
        self._note(state="playing", message=f"showing job {offer.job_id}")
        return True

    def _capture(self, job_id: str) -> None:
        self._note(state="capturing", message=f"capture of job {job_id} over {self.cfg.planes} planes")
        try:
            run_capture(player=self.player, stack_id=job_id, focus=self.focus, planes=list(range(self.cfg.planes)),
                        passes=self.cfg.passes_per_plane, trigger=self.trigger, trigger_at=self.cfg.trigger_at,
                        settle_timeout_s=self.cfg.settle_timeout_s,
                        sequence_log=self.cfg.cache_dir / "capture.jsonl")
            log.info("capture of job %s done", job_id)
            self._note(state="idle", message=f"captured job {job_id}")
        except (FocusError, HookError) as exc:
            log.error("capture of job %s failed: %s", job_id, exc)
            self._note(state="error", message=f"capture of job {job_id} failed: {exc}")

    def run(self, stop: threading.Event, *, max_seconds: Optional[float] = None) -> None:
        """Run until ``stop`` is set; the SLM is used from this (the calling) thread only."""
        log.info("agent %s for display %s: server %s, slm %s, policy %s, cache %s", __version__, self.cfg.display,
                 self.cfg.server_url, self.cfg.slm, self.cfg.policy, self.cfg.cache_dir)
        if self.focus is not None:
            try:
                log.info("focus controller %s: %s", self.focus.url, self.focus.connect())
            except FocusError as exc:
                log.warning("focus controller not available yet: %s", exc)
        sync = threading.Thread(target=self._sync_loop, args=(stop,), name="agent-sync", daemon=True)
        sync.start()
        t_end = None if max_seconds is None else time.monotonic() + max_seconds
        pending_play = False
        try:
            while not stop.is_set():
                if t_end is not None and time.monotonic() >= t_end:
                    break
                offer = self._take_offer()
                if offer is not None:
                    pending_play = self._load(offer)
                job = self._showing
                if job is None or not pending_play and self.cfg.policy != "loop":
                    stop.wait(0.05)
                    continue
                if self.cfg.policy == "loop":
                    self.player.play(passes=1, stop_event=stop)
                elif self.cfg.policy == "once":
                    self.player.play(passes=1, stop_event=stop)
                    self.slm.blank()
                    with self._lock:
                        self._showing = None
                    self._note(state="idle", message=f"played job {job} once")
                else:
                    self._capture(job)
                pending_play = False
        finally:
            stop.set()
            sync.join(timeout=self.cfg.request_timeout_s + 1)
            try:
                with self._lock:
                    self._showing = None
                self._note(state="stopped", message="agent stopped")
                self._heartbeat()
            except (TransientError, ServiceError):
                pass
            self.client.close()
            if self.focus is not None:
                self.focus.close()
            self.slm.close()
            log.info("agent stopped; %d frames shown", self.player.total.frames_shown)
