"""`holo focus-sim`: a simulated focus controller speaking docs/focus_protocol.md over TCP or a pty."""

from __future__ import annotations

import signal
import sys
import threading
from pathlib import Path
from typing import Optional

import typer

from holo.common import fail


def register(app: typer.Typer) -> None:
    app.command("focus-sim")(focus_sim)


def focus_sim(
    listen: Optional[str] = typer.Option(None, "--listen", help="HOST:PORT for TCP (clients use socket://HOST:PORT); "
                                                            "port 0 picks a free one"),
    pty: bool = typer.Option(False, "--pty", help="Serve on a pseudo-terminal; prints its path"),
    link: Optional[Path] = typer.Option(None, "--link", help="With --pty: a symlink to the pty (stable path)"),
    planes: int = typer.Option(5, "--planes", min=1, max=64, help="Number of focus planes"),
    plane_step: int = typer.Option(400, "--plane-step", min=1, help="Steps between planes (plane k at k*step)"),
    move_time_s: float = typer.Option(0.2, "--move-time-s", min=0.0, help="Seconds a move takes"),
    settle_s: float = typer.Option(0.05, "--settle-s", min=0.0, help="Seconds to settle after a move"),
    reset_delay_s: float = typer.Option(0.5, "--reset-delay-s", min=0.0,
                                        help="TCP: seconds each new connection 'boots' (input lost) before READY"),
    log_file: Optional[Path] = typer.Option(None, "--log", help="Append every line received/sent with its time"),
) -> None:
    """Run a simulated focus controller until interrupted (SIGINT/SIGTERM)."""
    from display_agent.focus.sim import FocusSimulator, serve_pty, serve_tcp

    if (listen is None) == (not pty):
        fail("give exactly one of --listen HOST:PORT or --pty")
    if link is not None and not pty:
        fail("--link needs --pty")
    positions = [k * plane_step for k in range(planes)]
    log = open(log_file, "a") if log_file else None
    sim = FocusSimulator(planes=positions, travel=(0, max(positions[-1], 1) + plane_step), move_time_s=move_time_s,
                         settle_s=settle_s, log=log)
    stop = threading.Event()

    def on_signal(signum: int, frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)

    def say(text: str) -> None:
        print(text, flush=True)

    try:
        if pty:
            serve_pty(sim, link=link, stop=stop, on_ready=lambda p: say(f"pty {p}"))
        else:
            host, _, port_s = (listen or "").rpartition(":")
            try:
                port = int(port_s)
            except ValueError:
                fail(f"--listen must be HOST:PORT, got {listen!r}")
            if not (0 <= port <= 65535) or not host:
                fail(f"--listen must be HOST:PORT with port in [0, 65535], got {listen!r}")
            try:
                serve_tcp(sim, host, port, reset_delay_s=reset_delay_s, stop=stop,
                          on_listen=lambda h, p: say(f"listening {h}:{p}"))
            except OSError as exc:
                fail(f"cannot listen on {listen}: {exc}", code=1)
    finally:
        if log is not None:
            log.close()
    sys.exit(0)
