"""`holo agent`: the display agent daemon, plus `holo agent capture` / `holo agent play` on a local stack.

Light imports only (numpy, httpx, pyserial, pygame lazily): no torch, Mitsuba or Dr.Jit (docs/design.md §1).
Settings: defaults < --config FILE (TOML/JSON) < HOLO_AGENT_* environment < options (docs/display_agent.md).
"""

from __future__ import annotations

import json
import logging
import re
import signal
import sys
import threading
from pathlib import Path
from typing import Any, Optional

import typer

from holo.common import fail

agent_app = typer.Typer(invoke_without_command=True, no_args_is_help=False, add_completion=False,
                        help="Display agent: play the service's stacks on an SLM, drive the focus controller.")


def register(app: typer.Typer) -> None:
    app.add_typer(agent_app, name="agent")


def _setup_logging(log_file: Optional[Path], verbose: bool) -> None:
    fmt = logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s")
    root = logging.getLogger("holo")
    root.setLevel(logging.DEBUG if verbose else logging.INFO)
    root.handlers.clear()
    err = logging.StreamHandler(sys.stderr)
    err.setFormatter(fmt)
    root.addHandler(err)
    if log_file is not None:
        Path(log_file).parent.mkdir(parents=True, exist_ok=True)
        fh = logging.FileHandler(log_file)
        fh.setFormatter(fmt)
        root.addHandler(fh)


def _config(config: Optional[Path], overrides: dict[str, Any]):
    from display_agent.config import ConfigError, load_config

    try:
        return load_config(config, overrides=overrides)
    except ConfigError as exc:
        fail(str(exc))


def _stop_on_signals() -> threading.Event:
    stop = threading.Event()

    def handler(signum: int, frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGINT, handler)
    return stop


@agent_app.callback()
def agent(
    ctx: typer.Context,
    config: Optional[Path] = typer.Option(None, "--config", help="Config file (TOML or JSON)"),
    server: Optional[str] = typer.Option(None, "--server", help="Service URL (HOLO_AGENT_SERVER_URL)"),
    token: Optional[str] = typer.Option(None, "--token", help="Bearer token, scope agent (HOLO_AGENT_TOKEN)"),
    display: Optional[str] = typer.Option(None, "--display", help="Display name"),
    slm: Optional[str] = typer.Option(None, "--slm", help="sim:DIR | window[:MONITOR[:WxH]] | null"),
    focus: Optional[str] = typer.Option(None, "--focus", help="Focus controller: port or URL (socket://h:p)"),
    policy: Optional[str] = typer.Option(None, "--policy", help="loop | once | capture"),
    rate_hz: Optional[float] = typer.Option(None, "--rate-hz", help="SLM frame slots per second"),
    lut: Optional[Path] = typer.Option(None, "--lut", help="Per-wavelength lookup table (JSON or .npy)"),
    cache_dir: Optional[Path] = typer.Option(None, "--cache-dir", help="Local stack cache"),
    poll_interval_s: Optional[float] = typer.Option(None, "--poll-s", help="Seconds between service polls"),
    log_file: Optional[Path] = typer.Option(None, "--log-file", help="Also log to this file"),
    max_seconds: Optional[float] = typer.Option(None, "--max-seconds", min=0.0, help="Exit after this long"),
    verbose: bool = typer.Option(False, "--verbose", "-v"),
) -> None:
    """Run the daemon (when no subcommand is given)."""
    if ctx.invoked_subcommand is not None:
        return
    cfg = _config(config, dict(server_url=server, token=token, display=display, slm=slm, focus_url=focus,
                               policy=policy, rate_hz=rate_hz, lut=lut, cache_dir=cache_dir,
                               poll_interval_s=poll_interval_s, log_file=log_file))
    if not cfg.server_url:
        fail("the daemon needs --server URL (or HOLO_AGENT_SERVER_URL, or server_url in --config)")
    _setup_logging(cfg.log_file, verbose)
    from display_agent.daemon import Agent
    from display_agent.slm.base import SLMError

    try:
        agent_obj = Agent(cfg)
    except (ValueError, SLMError) as exc:
        fail(str(exc))
    stop = _stop_on_signals()
    try:
        agent_obj.run(stop, max_seconds=max_seconds)
    except SLMError as exc:
        fail(f"SLM failed: {exc}", code=1)


def _load_local(stack: Path, lut: Optional[Path], levels_per_2pi: Optional[str]):
    from display_agent.phasemap import PhaseMapping
    from holocore.formats import StackError, open_stack

    try:
        st = open_stack(stack)
    except StackError as exc:
        fail(str(exc))
    try:
        scale: Any = 256
        if levels_per_2pi:
            vals = [int(v) for v in levels_per_2pi.split(",")]
            scale = vals[0] if len(vals) == 1 else vals
        mapping = PhaseMapping.from_options(lut=lut, levels_per_2pi=scale)
        levels = mapping.levels(st.phase, wavelengths_m=st.wavelengths_m)
    except ValueError as exc:
        fail(str(exc))
    stack_id = re.sub(r"[^A-Za-z0-9_.-]", "_", stack.stem).lstrip(".") or "stack"
    return st, levels, stack_id, mapping


@agent_app.command("capture")
def capture(
    stack: Path = typer.Option(..., "--stack", exists=True, dir_okay=False, help="STACK.npz to show"),
    slm: str = typer.Option("window:0", "--slm", help="sim:DIR | window[:MONITOR[:WxH]] | null"),
    focus: Optional[str] = typer.Option(None, "--focus", help="Focus controller port/URL (none: no moves)"),
    planes: int = typer.Option(5, "--planes", min=1, max=64, help="Focus planes 0..N-1 (MOVE PLANE k)"),
    positions: Optional[str] = typer.Option(None, "--positions", help="Comma-separated motor positions "
                                                                      "(MOVE POS x) instead of planes"),
    passes: int = typer.Option(1, "--passes", min=1, help="Stack passes per plane"),
    rate_hz: float = typer.Option(60.0, "--rate-hz", min=0.0, help="SLM frame slots per second"),
    lut: Optional[Path] = typer.Option(None, "--lut", help="Per-wavelength lookup table (JSON or .npy)"),
    levels_per_2pi: Optional[str] = typer.Option(None, "--levels-per-2pi", help="Gray level of 2pi (or per colour)"),
    trigger: Optional[str] = typer.Option(None, "--trigger", help="Camera trigger: command with {plane} "
                                                                  "{position} {index} {stack}, or py:mod:func"),
    trigger_at: str = typer.Option("after_play", "--trigger-at", help="before_play | after_play"),
    laser_hook: Optional[str] = typer.Option(None, "--laser-hook", help="Colour switch hook ({color})"),
    settle_timeout_s: float = typer.Option(30.0, "--settle-timeout-s", min=0.001),
    reconnect_timeout_s: float = typer.Option(30.0, "--reconnect-timeout-s", min=0.0),
    sequence_log: Optional[Path] = typer.Option(None, "--sequence-log", help="JSON lines of every step"),
    log_file: Optional[Path] = typer.Option(None, "--log-file"),
    verbose: bool = typer.Option(False, "--verbose", "-v"),
) -> None:
    """Capture sequence on a local stack: for each plane move, wait for SETTLED, play, trigger."""
    _setup_logging(log_file, verbose)
    if trigger_at not in ("before_play", "after_play"):
        fail(f"--trigger-at must be before_play or after_play, got {trigger_at!r}")
    pos_list = None
    if positions:
        try:
            pos_list = [int(v) for v in positions.split(",")]
        except ValueError:
            fail(f"--positions must be integers separated by commas, got {positions!r}")
    st, levels, stack_id, _ = _load_local(stack, lut, levels_per_2pi)
    from display_agent.capture import run_capture
    from display_agent.focus.client import FocusController, FocusError
    from display_agent.hooks import HookError, make_hook
    from display_agent.playback import Player
    from display_agent.slm.base import SLMError
    from display_agent.slm.drivers import open_slm

    try:
        trig = make_hook(trigger) if trigger else None
        laser = make_hook(laser_hook) if laser_hook else None
        dev = open_slm(slm)
    except (ValueError, SLMError) as exc:
        fail(str(exc))
    ctl = FocusController(focus, reconnect_timeout_s=reconnect_timeout_s) if focus else None
    try:
        dev.load(stack_id=stack_id, levels=levels)
        player = Player(dev, rate_hz=rate_hz, laser_hook=None if laser is None else (lambda c: laser(color=c)))
        steps = run_capture(player=player, stack_id=stack_id, focus=ctl,
                            planes=None if pos_list else list(range(planes)), positions=pos_list, passes=passes,
                            trigger=trig, trigger_at=trigger_at,  # type: ignore[arg-type]
                            settle_timeout_s=settle_timeout_s,
                            sequence_log=sequence_log)
    except (FocusError, HookError, SLMError) as exc:
        fail(f"capture failed: {exc}", code=1)
    finally:
        if ctl is not None:
            ctl.close()
        dev.close()
    typer.echo(json.dumps({"stack": stack_id, "sha256": st.sha256, "planes": [
        {"index": s.index, "plane": s.plane, "position": s.position, "frames": s.frames_shown,
         "seconds": round(s.seconds, 3)} for s in steps]}))


@agent_app.command("play")
def play(
    stack: Path = typer.Option(..., "--stack", exists=True, dir_okay=False, help="STACK.npz to show"),
    slm: str = typer.Option("window:0", "--slm", help="sim:DIR | window[:MONITOR[:WxH]] | null"),
    passes: int = typer.Option(1, "--passes", min=1, help="Passes over all frames and colours"),
    rate_hz: float = typer.Option(60.0, "--rate-hz", min=0.0),
    lut: Optional[Path] = typer.Option(None, "--lut"),
    levels_per_2pi: Optional[str] = typer.Option(None, "--levels-per-2pi"),
) -> None:
    """Play a local stack on the SLM (time-multiplexed, colour-sequential) and print the frame counts."""
    st, levels, stack_id, mapping = _load_local(stack, lut, levels_per_2pi)
    from display_agent.playback import Player
    from display_agent.slm.base import SLMError
    from display_agent.slm.drivers import open_slm

    try:
        dev = open_slm(slm)
    except (ValueError, SLMError) as exc:
        fail(str(exc))
    stop = _stop_on_signals()
    try:
        dev.load(stack_id=stack_id, levels=levels)
        stats = Player(dev, rate_hz=rate_hz).play(passes=passes, stop_event=stop)
    except SLMError as exc:
        fail(f"SLM failed: {exc}", code=1)
    finally:
        dev.close()
    typer.echo(json.dumps({"stack": stack_id, "sha256": st.sha256, "mapping": mapping.source,
                           "frames_shown": stats.frames_shown, "late": stats.late,
                           "seconds": round(stats.seconds, 4), "stopped": stats.stopped}))
