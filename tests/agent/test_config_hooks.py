"""Agent configuration (file < env < options) and hooks (camera trigger, laser switch)."""

from __future__ import annotations

import json
import sys
import types

import pytest

from display_agent.config import ConfigError, load_config
from display_agent.hooks import HookError, make_hook


def test_precedence_file_env_options(tmp_path):
    toml = tmp_path / "agent.toml"
    toml.write_text('[agent]\nserver_url = "http://file:1"\ndisplay = "lab1"\nrate_hz = 30\npolicy = "once"\n'
                    'levels_per_2pi = [220, 230, 240]\n')
    cfg = load_config(toml, env={})
    assert (cfg.server_url, cfg.display, cfg.rate_hz, cfg.policy, cfg.levels_per_2pi) == (
        "http://file:1", "lab1", 30.0, "once", [220, 230, 240])
    env = {"HOLO_AGENT_SERVER": "http://env:2/", "HOLO_AGENT_RATE_HZ": "120", "HOLO_AGENT_FOCUS": "socket://h:5"}
    cfg = load_config(toml, env=env, overrides={"rate_hz": 24.0, "display": None})
    assert cfg.server_url == "http://env:2" and cfg.rate_hz == 24.0 and cfg.display == "lab1"
    assert cfg.focus_url == "socket://h:5"
    js = tmp_path / "agent.json"
    js.write_text(json.dumps({"display": "lab2", "slm": "sim:/tmp/x"}))
    cfg = load_config(env={"HOLO_AGENT_CONFIG": str(js)})
    assert cfg.display == "lab2" and cfg.slm == "sim:/tmp/x"


def test_token_file(tmp_path):
    (tmp_path / "tok").write_text("abc123\n")
    assert load_config(env={}, overrides={"token_file": tmp_path / "tok"}).resolved_token() == "abc123"
    with pytest.raises(ConfigError, match="cannot read token_file"):
        load_config(env={}, overrides={"token_file": tmp_path / "nope"}).resolved_token()


@pytest.mark.parametrize("env, match", [
    ({"HOLO_AGENT_RATE_HZ": "-1"}, "rate_hz"),
    ({"HOLO_AGENT_SERVER_URL": "ftp://x"}, "server_url"),
    ({"HOLO_AGENT_DISPLAY": "../etc"}, "display"),
    ({"HOLO_AGENT_POLICY": "shuffle"}, "policy"),
    ({"HOLO_AGENT_LEVELS_PER_2PI": "300"}, "levels_per_2pi"),
    ({"HOLO_AGENT_COLOUR": "red"}, "unknown environment variable HOLO_AGENT_COLOUR"),
    ({"HOLO_AGENT_BACKOFF_BASE_S": "5", "HOLO_AGENT_BACKOFF_CAP_S": "1"}, "backoff_cap_s"),
])
def test_invalid_settings_name_the_field(env, match):
    with pytest.raises(ConfigError, match=match):
        load_config(env=env)


def test_bad_files(tmp_path):
    (tmp_path / "a.toml").write_text("server_url = ")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(tmp_path / "a.toml", env={})
    (tmp_path / "b.json").write_text("[1, 2]")
    with pytest.raises(ConfigError, match="must hold an object"):
        load_config(tmp_path / "b.json", env={})
    (tmp_path / "c.json").write_text('{"sever_url": "http://x"}')
    with pytest.raises(ConfigError, match="sever_url"):
        load_config(tmp_path / "c.json", env={})


def test_shell_hook_fills_fields_and_reports_failures(tmp_path):
    out = tmp_path / "marks"
    out.mkdir()
    make_hook(f"touch {out}/p{{plane}}_{{stack}}")(plane=3, stack="j9")
    assert (out / "p3_j9").is_file()
    with pytest.raises(HookError, match="exited 1"):
        make_hook(f"{sys.executable} -c 'import sys; sys.exit(1)'")()
    with pytest.raises(HookError, match="unknown field"):
        make_hook("echo {nope}")(plane=1)
    with pytest.raises(HookError, match="failed"):
        make_hook(f"{sys.executable} -c 'import time; time.sleep(5)'", timeout_s=0.3)()
    with pytest.raises(HookError, match="failed"):
        make_hook("/nonexistent/camera-trigger")()


def test_python_hook(monkeypatch):
    calls = []
    mod = types.ModuleType("fake_camera")
    mod.fire = lambda **kw: calls.append(kw)  # type: ignore[attr-defined]
    mod.broken = lambda **kw: 1 / 0  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "fake_camera", mod)
    make_hook("py:fake_camera:fire")(plane=2, position=800)
    assert calls == [{"plane": 2, "position": 800}]
    with pytest.raises(HookError, match="ZeroDivisionError"):
        make_hook("py:fake_camera:broken")()
    with pytest.raises(ValueError, match="cannot load hook"):
        make_hook("py:fake_camera:missing")
    with pytest.raises(ValueError, match="py:module:function"):
        make_hook("py:nocolon")


def test_agent_imports_nothing_heavy():
    # docs/design.md §1: the agent runs on a lab PC without torch, Mitsuba or Dr.Jit (and without holocore's numerics:
    # of holocore it reads only the numpy-only file formats, holocore.formats, and the pure-Python option model
    # and plug-in finder its commands' help and its SLM drivers need)
    import subprocess

    code = ("import sys, holo.app, display_agent.daemon, display_agent.slm.sim, display_agent.focus.sim; "
            "bad = [m for m in ('torch', 'mitsuba', 'drjit', 'scipy') if m in sys.modules]; "
            "bad += [m for m in sys.modules if m.startswith('holocore.') and m.split('.')[1] not in ('formats', 'options', 'plugins')]; "
            "print(bad); sys.exit(1 if bad else 0)")
    from tests.agent.helpers import env

    r = subprocess.run([sys.executable, "-c", code], env=env(), capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
