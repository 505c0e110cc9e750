"""One job-field list (service.jobfiles.JobFields): the request, the stored spec and job.json share it, and every
field is part of the result's content address, so two jobs that differ in one never share a result."""

from __future__ import annotations

from service.jobfiles import JobFields, JobFile, JobSpec
from service.job_rules import binding_max_spp
from service.models import JobRequest, cache_key
from service.settings import JobLimits

# a value other than the default for each field (frames lives in the effective optics, also in the address)
OTHER = {"preset": "fast", "frames": 3, "spp": 7, "render_time_limit_s": 5.0, "encoder": "dpac", "optimiser": "adam", "iterations": 9,
         "method": "direct", "wrp_planes": 1, "evaluate": True, "quality_db": 20.0, "max_spp": 7}
# a quality target is resolved into frames, spp and iterations before a job is stored (service/quality.py)
RESOLVED_AWAY = {"quality_db"}


def _key(req: JobRequest) -> str:
    return cache_key(req, scene_sha256="0" * 64, entry="scene.xml", code_version="test",
                     max_spp=binding_max_spp(req, JobLimits()))


def test_every_job_field_changes_the_content_address():
    assert set(OTHER) == set(JobFields.model_fields), "a new job field: give it a value here"
    base = JobRequest(scene_id="s1")
    for name, value in OTHER.items():
        other = JobRequest(scene_id="s1", **{name: value})
        assert _key(other) != _key(base), name
    # what is not a job field (the display it is for, a name for people) is not in the address
    assert _key(JobRequest(scene_id="s1", display="lab1", name="my job")) == _key(base)


def test_the_request_the_spec_and_the_job_file_share_the_fields():
    for model in (JobRequest, JobSpec, JobFile):
        assert set(JobFields.model_fields) <= set(model.model_fields), model.__name__
    stored = {k: v for k, v in OTHER.items() if k not in RESOLVED_AWAY}
    req = JobRequest(scene_id="s1", **{**stored, "method": "wrp", "wrp_planes": 3})
    spec = JobSpec(optics={}, **req.fields())
    assert spec.fields() == req.fields()
