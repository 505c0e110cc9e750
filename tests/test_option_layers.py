"""The hologram's options are written once (holocore.options.HologramOptions) and every layer takes them from
there: the CLIs' flags, the service's job fields, the job file the driver hands to the CLIs, the page's form and
docs/options.md. Each test names the layer an option went missing from."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import typer

from holo.app import app
from holo.common import hologram_options
from holocore.options import CLI_FLAGS, HologramOptions, check, explain, option_table
from holocore.plan.presets import MAX_WRP_PLANES
from service.jobfiles import JobFields, JobFile
from service.workers.driver import render_args, write_options

REPO = Path(__file__).resolve().parents[1]
# a value other than the default for every option
OTHER = {"preset": "fast", "frames": 3, "spp": 7, "max_spp": 9, "render_time_limit_s": 5.0, "encoder": "dpac",
         "optimiser": "adam", "iterations": 11, "quality_db": None, "method": "wrp", "wrp_planes": 6}
# options the page's form does not offer, and why
FORM_LEAVES_OUT = {"max_spp": "the service's own cap bounds the preset's rays; `holo submit --max-spp` and the API "
                              "set a lower one"}


def _command_flags(name: str) -> set[str]:
    cmd = typer.main.get_command(app)
    return {opt for p in cmd.commands[name].params for opt in p.opts}


def test_every_option_has_its_flags_and_the_commands_take_them():
    assert set(CLI_FLAGS) == set(HologramOptions.model_fields) == set(OTHER)
    for i, command in enumerate(("render", "encode", "submit")):
        flags = _command_flags(command)
        for name, spelled in CLI_FLAGS.items():
            if spelled[i] is not None:
                assert spelled[i] in flags, f"`holo {command}` lacks {spelled[i]} ({name})"
        assert "--options-json" in flags, command


def test_the_service_job_fields_are_the_options_and_evaluate():
    assert set(JobFields.model_fields) == set(HologramOptions.model_fields) | {"evaluate"}
    for name, field in HologramOptions.model_fields.items():  # the same limits and defaults, not restated
        assert JobFields.model_fields[name].metadata == field.metadata, name
        assert JobFields.model_fields[name].default == field.default, name


def test_the_driver_hands_every_option_to_the_clis_unchanged(tmp_path):
    spec = JobFile(job_id="j", scene_path="s.xml", optics={}, **{k: v for k, v in OTHER.items() if v is not None})
    write_options(spec, tmp_path)
    args = render_args(spec, "p.jsonl", tmp_path)
    assert not set(args) & {f for flags in CLI_FLAGS.values() for f in flags if f}, "an option restated as a flag"
    for command in ("render", "encode"):
        read = hologram_options(Path(args[args.index("--options-json") + 1]), command)
        assert read == spec.hologram_options(), command
        assert read.model_dump() == {**HologramOptions().model_dump(), **{k: v for k, v in OTHER.items()
                                                                         if v is not None}}


def test_flags_override_the_document_and_refusals_are_one_line_in_the_commands_words(tmp_path):
    doc = tmp_path / "o.json"
    doc.write_text('{"spp": 7, "preset": "fast"}')
    assert hologram_options(doc, "render", spp=9).model_dump(include={"spp", "preset"}) == {"spp": 9, "preset": "fast"}
    with pytest.raises(ValueError, match=r"^spp must be in 1\.\.1000000, got 0$"):
        check(spp=0)
    from pydantic import ValidationError

    for fields, command, words in [({"wrp_planes": 9}, "submit", f"--wrp-planes must be in 1..{MAX_WRP_PLANES}"),
                                   ({"render_time_limit_s": 5.0}, "render", None),
                                   ({"encoder": "x"}, "encode", "--method: Input should be 'sgd' or 'dpac'"),
                                   ({"spp": 3, "quality_db": 20}, "render", "quality_db chooses spp")]:
        try:
            HologramOptions(**fields)
        except ValidationError as exc:
            line = explain(exc, command)
            assert words is not None and words in line and "\n" not in line, line
        else:
            assert words is None, fields


def test_the_page_form_sends_every_option():
    form = (REPO / "service/web/submit_form.js").read_text()
    for name in HologramOptions.model_fields:
        if name not in FORM_LEAVES_OUT:
            assert re.search(rf"\b{name}\b", form), f"the form never sends {name}"


def test_the_service_answers_every_options_limits():
    from service.job_rules import option_limits
    from service.settings import JobLimits

    tight = option_limits(JobLimits(max_frames=12, max_spp=300, max_iterations=40, max_render_time_s=60.0))
    assert set(HologramOptions.model_fields) <= set(tight)
    assert (tight["frames"]["max"], tight["spp"]["max"], tight["iterations"]["max"]) == (12, 300, 40)
    assert tight["render_time_limit_s"]["max"] == 60.0 and tight["wrp_planes"] == {
        "min": 1, "max": MAX_WRP_PLANES, "choices": ["auto"], "default": "auto"}
    assert tight["preset"]["choices"] == ["fast", "balanced", "reference"]


def test_docs_hold_the_option_table():
    assert option_table() in (REPO / "docs/options.md").read_text(), "rerun: python -m holocore.options"
