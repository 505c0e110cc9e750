"""Focus controller client over pyserial's ``serial_for_url`` (real ports, ``socket://``, a pty path, ``loop://``).

Opening a real Arduino's port resets it (DTR), and bytes sent while its bootloader runs are lost, so
:meth:`FocusController.connect` waits for the ``READY`` banner or pings until a ``PONG`` comes back, within
``ready_timeout_s``. Each request waits ``reply_timeout_s`` for the reply with its id (stale replies and
banners are skipped). A lost line (cable pulled, controller restarted) raises :class:`FocusDisconnected`;
:meth:`goto` reconnects with capped, jittered backoff and re-issues the move.
"""

from __future__ import annotations

import itertools
import logging
import time
from dataclasses import dataclass
from typing import Callable, Optional

import serial

from display_agent.backoff import Backoff
from display_agent.focus.protocol import Reply, format_request, parse_kv, parse_reply

__all__ = ["FocusError", "FocusTimeout", "FocusNotSettled", "FocusDisconnected", "FocusStatus", "FocusController"]

log = logging.getLogger("holo.agent.focus")


class FocusError(RuntimeError):
    """The controller answered ERR (``code`` is the protocol's error code) or misbehaved."""

    def __init__(self, message: str, *, code: str = "") -> None:
        super().__init__(message)
        self.code = code


class FocusTimeout(FocusError):
    """No reply (or no settle) within the allowed time."""


class FocusNotSettled(FocusTimeout):
    """The controller answers but the lens did not settle in time (not retried by reconnecting)."""


class FocusDisconnected(FocusError):
    """The serial line is gone (or could not be opened)."""


@dataclass(frozen=True)
class FocusStatus:
    state: str  # MOVING | SETTLING | SETTLED
    pos: int
    target: int

    @property
    def settled(self) -> bool:
        return self.state == "SETTLED"


class FocusController:
    """Client of one focus controller. ``url``: anything ``serial.serial_for_url`` opens."""

    def __init__(self, url: str, *, baudrate: int = 115200, reply_timeout_s: float = 2.0,
                 ready_timeout_s: float = 10.0, ping_interval_s: float = 0.5, poll_interval_s: float = 0.02,
                 reconnect_timeout_s: float = 30.0, backoff: Optional[Backoff] = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not url:
            raise ValueError("url must name a serial port or a serial_for_url URL (socket://HOST:PORT, ...)")
        for name, v in (("reply_timeout_s", reply_timeout_s), ("ready_timeout_s", ready_timeout_s),
                        ("ping_interval_s", ping_interval_s), ("poll_interval_s", poll_interval_s)):
            if not (v > 0):
                raise ValueError(f"{name} must be > 0 seconds, got {v}")
        if not (reconnect_timeout_s >= 0):
            raise ValueError(f"reconnect_timeout_s must be >= 0 seconds, got {reconnect_timeout_s}")
        self.url = url
        self.baudrate = baudrate
        self.reply_timeout_s = reply_timeout_s
        self.ready_timeout_s = ready_timeout_s
        self.ping_interval_s = ping_interval_s
        self.poll_interval_s = poll_interval_s
        self.reconnect_timeout_s = reconnect_timeout_s
        self.backoff = backoff or Backoff(base_s=0.2, cap_s=2.0, jitter=0.3)
        self._clock = clock
        self._ser: Optional[serial.SerialBase] = None
        self._buf = b""
        self._ids = itertools.count(1)
        self.banner: Optional[str] = None
        self.reconnects = 0  # successful connects after the first
        self._connected_once = False

    # connection -----------------------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self._ser is not None

    def connect(self) -> str:
        """Open the line and wait until the controller answers; returns its VERSION payload."""
        self.close()
        try:
            self._ser = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=0.02, write_timeout=1.0)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise FocusDisconnected(f"cannot open focus controller {self.url}: {exc}") from exc
        self._buf = b""
        deadline = self._clock() + self.ready_timeout_s
        next_ping = self._clock()
        ping_id = ""
        while True:
            now = self._clock()
            if now >= deadline:
                self.close()
                raise FocusTimeout(f"focus controller {self.url} did not answer within {self.ready_timeout_s} s "
                                   "(no READY banner, no PONG)")
            if now >= next_ping:
                ping_id = self._send("PING")
                next_ping = now + self.ping_interval_s
            line = self._readline(min(deadline, next_ping))
            if line is None:
                continue
            if line.startswith("READY"):
                self.banner = line
                log.info("focus controller %s: %s", self.url, line)
                next_ping = self._clock()  # ping right away: it is up now
                continue
            rep = parse_reply(line)
            if rep is not None and rep.id == ping_id and rep.ok:
                break
        version = self.request("VERSION")
        if self._connected_once:
            self.reconnects += 1
            log.warning("focus controller %s reconnected (%s)", self.url, version)
        self._connected_once = True
        return version

    def close(self) -> None:
        if self._ser is not None:
            try:
                self._ser.close()
            except Exception:  # noqa: BLE001 - closing a dead port may fail in many ways
                pass
            self._ser = None

    def __enter__(self) -> "FocusController":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # line I/O ---------------------------------------------------------------------------------------------
    def _lost(self, exc: BaseException) -> FocusDisconnected:
        self.close()
        return FocusDisconnected(f"focus controller line {self.url} lost: {exc}")

    def _send(self, verb: str, *args: object) -> str:
        if self._ser is None:
            raise FocusDisconnected(f"focus controller {self.url} is not connected")
        rid = str(next(self._ids) % 100_000_000 or 1)
        data = format_request(rid, verb, *args).encode("ascii")
        try:
            self._ser.write(data)
            self._ser.flush()
        except (serial.SerialException, OSError) as exc:
            raise self._lost(exc) from exc
        return rid

    def _readline(self, deadline: float) -> Optional[str]:
        """One line (without newline) or None at the deadline."""
        while True:
            if b"\n" in self._buf:
                raw, self._buf = self._buf.split(b"\n", 1)
                return raw.decode("ascii", "replace").rstrip("\r")
            if self._ser is None:
                raise FocusDisconnected(f"focus controller {self.url} is not connected")
            if self._clock() >= deadline:
                return None
            try:
                chunk = self._ser.read(max(1, self._ser.in_waiting))
            except (serial.SerialException, OSError) as exc:
                raise self._lost(exc) from exc
            self._buf += chunk
            if len(self._buf) > 4096:  # a line this long is noise
                self._buf = b""

    def request(self, verb: str, *args: object, timeout_s: Optional[float] = None) -> str:
        """Send one request and return the payload of its OK; FocusError on ERR, FocusTimeout without reply."""
        rid = self._send(verb, *args)
        deadline = self._clock() + (self.reply_timeout_s if timeout_s is None else timeout_s)
        while True:
            line = self._readline(deadline)
            if line is None:
                raise FocusTimeout(f"no reply to '{verb}' (id {rid}) from {self.url} within "
                                   f"{self.reply_timeout_s if timeout_s is None else timeout_s} s")
            if line.startswith("READY"):  # the controller rebooted under us
                self.banner = line
                log.warning("focus controller %s rebooted (%s)", self.url, line)
                continue
            rep: Optional[Reply] = parse_reply(line)
            if rep is None or rep.id != rid:
                continue  # comment, echo or a stale reply
            if not rep.ok:
                raise FocusError(f"focus controller refused '{verb} {' '.join(map(str, args))}': "
                                 f"{rep.code} {rep.message}", code=rep.code)
            return rep.payload

    # commands ---------------------------------------------------------------------------------------------
    def ping(self) -> None:
        if self.request("PING") != "PONG":
            raise FocusError("PING did not answer PONG")

    def planes(self) -> list[int]:
        kv = parse_kv(self.request("PLANES"))
        try:
            return [int(v) for v in kv.get("pos", "").split(",") if v]
        except ValueError as exc:
            raise FocusError(f"bad PLANES reply: {kv}") from exc

    def status(self) -> FocusStatus:
        kv = parse_kv(self.request("STATUS"))
        try:
            return FocusStatus(state=kv["state"], pos=int(kv["pos"]), target=int(kv.get("target", kv["pos"])))
        except (KeyError, ValueError) as exc:
            raise FocusError(f"bad STATUS reply: {kv}") from exc

    def move_plane(self, plane: int) -> int:
        """Start moving to plane ``plane`` (index into the controller's table); returns the target position."""
        if plane < 0:
            raise ValueError(f"plane must be >= 0, got {plane}")
        return int(parse_kv(self.request("MOVE", "PLANE", int(plane))).get("target", -1))

    def move_pos(self, pos: int) -> int:
        """Start moving to absolute position ``pos`` (motor steps); returns the target."""
        return int(parse_kv(self.request("MOVE", "POS", int(pos))).get("target", pos))

    def wait_settled(self, *, timeout_s: float = 30.0) -> FocusStatus:
        """Poll STATUS until SETTLED; FocusTimeout after ``timeout_s``."""
        deadline = self._clock() + timeout_s
        while True:
            st = self.status()
            if st.settled:
                return st
            if self._clock() >= deadline:
                raise FocusNotSettled(f"focus controller not settled after {timeout_s} s ({st.state} pos={st.pos} "
                                   f"target={st.target})")
            time.sleep(self.poll_interval_s)

    def ensure_connected(self) -> None:
        """Connect, retrying with backoff for up to ``reconnect_timeout_s``."""
        if self._ser is not None:
            return
        deadline = self._clock() + self.reconnect_timeout_s
        self.backoff.reset()
        while True:
            try:
                self.connect()
                self.backoff.reset()
                return
            except FocusDisconnected as exc:
                err: FocusError = exc
            except FocusTimeout as exc:
                err = exc
            delay = self.backoff.next_delay()
            if self._clock() + delay > deadline:
                raise FocusDisconnected(f"focus controller {self.url} unreachable for {self.reconnect_timeout_s} s: "
                                        f"{err}") from err
            log.warning("focus controller %s: %s; retrying in %.2f s", self.url, err, delay)
            time.sleep(delay)

    def goto(self, *, plane: Optional[int] = None, pos: Optional[int] = None,
             settle_timeout_s: float = 30.0) -> FocusStatus:
        """Move to a plane or a position and wait until settled. A lost line is reconnected (backoff, up to
        ``reconnect_timeout_s``) and the move re-issued from the start; ERR replies are not retried."""
        if (plane is None) == (pos is None):
            raise ValueError("give exactly one of plane or pos")
        deadline = self._clock() + self.reconnect_timeout_s
        while True:
            try:
                self.ensure_connected()
                target = self.move_plane(plane) if plane is not None else self.move_pos(pos)  # type: ignore[arg-type]
                st = self.wait_settled(timeout_s=settle_timeout_s)
                if st.pos != target:
                    raise FocusError(f"settled at {st.pos}, not at the target {target}")
                return st
            except FocusNotSettled:
                raise
            except (FocusDisconnected, FocusTimeout) as exc:
                self.close()
                if self._clock() >= deadline:
                    raise
                log.warning("focus controller %s: %s; reconnecting and repeating the move", self.url, exc)
