"""A simulated focus controller that speaks the protocol of docs/focus_protocol.md.

The lens moves for ``move_time_s`` (linear in time) and then settles for ``settle_s``: ``MOVE`` is acknowledged
at once (``OK MOVING``) and ``STATUS`` says ``SETTLED`` only later, as on the real rig. Transports: a TCP
server (clients use ``socket://HOST:PORT``), where each new connection behaves like an Arduino reset (input
is dropped for ``reset_delay_s``, then the ``READY`` banner), and a pseudo-terminal (clients open the slave
path as a serial port). Every received and sent line is logged with its time (``<unix time> RX|TX <line>``).
"""

from __future__ import annotations

import os
import select
import socket
import threading
import time
import tty
from pathlib import Path
from typing import Callable, Optional, TextIO

from display_agent.focus.protocol import ID_RE, MAX_LINE, PROTOCOL_VERSION

__all__ = ["FocusSimulator", "serve_tcp", "serve_pty", "FIRMWARE_NAME", "FIRMWARE_VERSION"]

FIRMWARE_NAME = "focus_sim"
FIRMWARE_VERSION = "1.0"


class FocusSimulator:
    """Protocol state machine: ``handle(line) -> reply lines``. Positions are integer motor steps."""

    def __init__(self, *, planes: list[int], travel: tuple[int, int] = (0, 10_000), move_time_s: float = 0.2,
                 settle_s: float = 0.05, clock: Callable[[], float] = time.monotonic,
                 log: Optional[TextIO] = None) -> None:
        if not planes:
            raise ValueError("planes must list at least one position")
        if travel[0] >= travel[1] or any(not travel[0] <= p <= travel[1] for p in planes):
            raise ValueError(f"planes {planes} must lie inside travel {travel}")
        if move_time_s < 0 or settle_s < 0:
            raise ValueError("move_time_s and settle_s must be >= 0 seconds")
        self.planes = [int(p) for p in planes]
        self.travel = travel
        self.move_time_s = move_time_s
        self.settle_s = settle_s
        self._clock = clock
        self._log = log
        self._lock = threading.Lock()
        self._start_pos = 0
        self._target = 0
        self._t_start = -1e9

    def log(self, direction: str, line: str) -> None:
        if self._log is not None:
            self._log.write(f"{time.time():.6f} {direction} {line}\n")
            self._log.flush()

    def banner(self) -> str:
        return (f"READY {FIRMWARE_NAME} {FIRMWARE_VERSION} proto={PROTOCOL_VERSION} planes={len(self.planes)}")

    def _state(self) -> tuple[str, int]:
        dt = self._clock() - self._t_start
        if dt >= self.move_time_s + self.settle_s:
            return "SETTLED", self._target
        if dt >= self.move_time_s:
            return "SETTLING", self._target
        frac = dt / self.move_time_s if self.move_time_s > 0 else 1.0
        return "MOVING", int(round(self._start_pos + frac * (self._target - self._start_pos)))

    def _move(self, target: int) -> None:
        _, pos = self._state()
        self._start_pos, self._target, self._t_start = pos, target, self._clock()

    def handle(self, line: str) -> list[str]:
        """One request line (without newline) -> reply lines."""
        with self._lock:
            return self._handle(line.strip())

    def _handle(self, line: str) -> list[str]:
        if not line or line.startswith("#"):
            return []
        parts = line.split()
        rid = parts[0]
        if not ID_RE.match(rid) or len(parts) < 2:
            return [f"? ERR SYNTAX expected '<id> <VERB> [ARGS]', got {line[:40]!r}"]
        verb, args = parts[1].upper(), parts[2:]

        def err(code: str, msg: str) -> list[str]:
            return [f"{rid} ERR {code} {msg}"]

        if len(line) > MAX_LINE:
            return err("SYNTAX", f"line longer than {MAX_LINE} characters")
        if verb == "PING":
            return [f"{rid} OK PONG"]
        if verb == "VERSION":
            return [f"{rid} OK {FIRMWARE_NAME} {FIRMWARE_VERSION} proto={PROTOCOL_VERSION}"]
        if verb == "PLANES":
            return [f"{rid} OK n={len(self.planes)} pos={','.join(str(p) for p in self.planes)}"]
        if verb == "STATUS":
            state, pos = self._state()
            return [f"{rid} OK {state} pos={pos} target={self._target}"]
        if verb == "STOP":
            _, pos = self._state()
            self._start_pos = self._target = pos
            self._t_start = -1e9
            return [f"{rid} OK SETTLED pos={pos} target={pos}"]
        if verb == "MOVE":
            if len(args) != 2 or args[0].upper() not in ("PLANE", "POS"):
                return err("ARG", "usage: MOVE PLANE <k> | MOVE POS <steps>")
            try:
                value = int(args[1])
            except ValueError:
                return err("ARG", f"not an integer: {args[1]}")
            if args[0].upper() == "PLANE":
                if not 0 <= value < len(self.planes):
                    return err("RANGE", f"plane must be in [0, {len(self.planes) - 1}]")
                self._move(self.planes[value])
                return [f"{rid} OK MOVING plane={value} target={self.planes[value]}"]
            if not self.travel[0] <= value <= self.travel[1]:
                return err("RANGE", f"pos must be in [{self.travel[0]}, {self.travel[1]}]")
            self._move(value)
            return [f"{rid} OK MOVING target={value}"]
        return err("UNKNOWN", f"unknown command {verb}")


def _serve_stream(sim: FocusSimulator, recv: Callable[[], bytes], send: Callable[[bytes], None],
                  stop: threading.Event) -> None:
    """Read lines from ``recv`` (b"" = closed), answer through ``send``."""
    buf = b""
    while not stop.is_set():
        data = recv()
        if data is None:
            continue
        if data == b"":
            return
        buf += data
        while b"\n" in buf:
            raw, buf = buf.split(b"\n", 1)
            text = raw.decode("ascii", "replace").rstrip("\r")
            sim.log("RX", text)
            for out in sim.handle(text):
                sim.log("TX", out)
                send(out.encode("ascii", "replace") + b"\n")
        if len(buf) > 4 * MAX_LINE:  # garbage without newlines: drop it
            buf = b""


def serve_tcp(sim: FocusSimulator, host: str, port: int, *, reset_delay_s: float = 0.5,
              stop: Optional[threading.Event] = None, on_listen: Optional[Callable[[str, int], None]] = None) -> None:
    """Serve clients one at a time on TCP (a serial line has one end). Each connection starts like an
    Arduino that the port's DTR just reset: input during ``reset_delay_s`` is lost, then ``READY``."""
    stop = stop or threading.Event()
    srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    srv.bind((host, port))
    srv.listen(1)
    srv.settimeout(0.2)
    if on_listen is not None:
        on_listen(*srv.getsockname()[:2])
    try:
        while not stop.is_set():
            try:
                conn, _ = srv.accept()
            except socket.timeout:
                continue
            with conn:
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                sim.log("--", "connect (reset)")
                t_end = time.monotonic() + reset_delay_s
                conn.settimeout(0.05)
                while time.monotonic() < t_end:  # booting: what arrives now is lost
                    try:
                        if conn.recv(4096) == b"":
                            break
                    except socket.timeout:
                        pass
                    except OSError:
                        break
                try:
                    banner = sim.banner()
                    sim.log("TX", banner)
                    conn.sendall(banner.encode() + b"\n")
                except OSError:
                    continue

                def recv(conn: socket.socket = conn) -> Optional[bytes]:
                    try:
                        return conn.recv(4096)
                    except socket.timeout:
                        return None
                    except OSError:
                        return b""

                try:
                    _serve_stream(sim, recv, conn.sendall, stop)
                except OSError:
                    pass
                sim.log("--", "disconnect")
    finally:
        srv.close()


def serve_pty(sim: FocusSimulator, *, link: Optional[Path] = None, stop: Optional[threading.Event] = None,
              on_ready: Optional[Callable[[str], None]] = None) -> None:
    """Serve over a pseudo-terminal: clients open the slave path (printed through ``on_ready``; ``link``
    makes a stable symlink to it) as a serial port. The banner is sent once at start."""
    stop = stop or threading.Event()
    master, slave = os.openpty()
    tty.setraw(slave)  # no echo, no newline translation: a plain byte line like a UART
    path = os.ttyname(slave)
    if link is not None:
        link = Path(link)
        tmp = link.with_name(f".{link.name}.tmp")
        tmp.unlink(missing_ok=True)
        tmp.symlink_to(path)
        os.replace(tmp, link)
    if on_ready is not None:
        on_ready(path)
    banner = sim.banner()
    sim.log("TX", banner)
    os.write(master, banner.encode() + b"\n")

    def recv() -> Optional[bytes]:
        r, _, _ = select.select([master], [], [], 0.1)
        if not r:
            return None
        try:
            return os.read(master, 4096)
        except OSError:  # no slave open right now (EIO): wait for the next client
            time.sleep(0.05)
            return None

    def send(data: bytes) -> None:
        os.write(master, data)

    try:
        # keep our slave fd open so the master stays usable between clients
        _serve_stream(sim, recv, send, stop)
    finally:
        os.close(master)
        os.close(slave)
        if link is not None:
            Path(link).unlink(missing_ok=True)
