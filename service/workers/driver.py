"""One job, in its own process group: `holo render`, `holo encode`, the 8-bit frames zip, then the preview image
and the web page's pictures (``service.workers.pictures``: the preview as `holo view` makes it, focal sweep and
view grid under ``pictures/``; one process), and for a job that asks for it the evaluation against ground truth
(`holo evaluate`, under ``evaluation/``: service/workers/evaluation.py).

Run as ``python -m service.workers.driver JOB_DIR [--parent-pid PID]``. ``JOB_DIR/job.json`` says what to do;
the driver writes ``step.json`` as each step starts, each CLI appends ``progress-<step>.jsonl``, and at the end
``status.json`` (atomically) says how it went. Exit codes: 0 done, 3 failed for good (bad input, the scene
refused; ``status.json`` holds the message, and a step that crashed on its own: SIGSEGV, SIGBUS, SIGILL, SIGFPE,
SIGABRT, which the same input would give again), anything else (SIGKILL, the driver's own death) may be
retried.

Each step runs in an empty working folder of its own (a temporary one, removed after it), with absolute paths
into the job dir: nothing a working directory holds is ever looked up (Mitsuba's default file resolver starts
with it). The driver first lowers its own kernel resource limits to ``job.json``'s ``limits``
(service/workers/limits.py; the steps inherit them); a step they stop fails for good, saying which limit.

The driver leads its process group (the scheduler starts it with ``start_new_session``); the CLIs inherit the
group, so one ``killpg`` stops the whole job. It asks the kernel for SIGTERM when its parent dies
(``PR_SET_PDEATHSIG``) and then kills its group, and each CLI gets SIGKILL when the driver dies, so no render
outlives the server (or Ray worker) that started it.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import resource
import signal
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path
from typing import Any, Optional

from service.jobfiles import (
    STEPS,
    ArtifactInfo,
    JobFile,
    RunStatus,
    Step,
    read_job_file,
)
from service.workers.evaluation import run_evaluation
from service.workers.limits import ProcessLimits, current_limits, explain_limit

__all__ = ["main", "EXIT_FAILED", "EXIT_RETRY", "write_json_atomic", "write_render_plan", "frames_zip",
           "preview_focus_mm", "run_job"]

EXIT_FAILED = 3
EXIT_RETRY = 75


def write_json_atomic(path: Path, doc: Any) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(doc, indent=1))
    os.replace(tmp, path)


def _set_pdeathsig(sig: int) -> None:
    """Ask Linux to send ``sig`` to this process when its parent dies (PR_SET_PDEATHSIG; no-op elsewhere)."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, int(sig), 0, 0, 0)
    except (OSError, AttributeError):
        pass


def _die_with_parent(parent_pid: Optional[int]) -> None:
    _set_pdeathsig(signal.SIGTERM)
    if parent_pid is not None and os.getppid() != parent_pid:
        sys.exit(EXIT_RETRY)  # the parent died before prctl took effect


def _child_dies_with_driver() -> None:  # preexec_fn of the CLIs (the driver is single-threaded)
    _set_pdeathsig(signal.SIGKILL)


def _on_term(signum, frame) -> None:  # noqa: ARG001
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        os.killpg(os.getpgrp(), signal.SIGKILL)
    finally:
        os._exit(128 + signum)


# Signals a step raises on itself when its input crashes it (Mitsuba on a malformed scene): a rerun crashes the
# same way, so such a failure is final; so is a step its CPU-time or file-size limit stopped.
_CRASH_SIGNALS = frozenset({signal.SIGSEGV, signal.SIGBUS, signal.SIGILL, signal.SIGFPE, signal.SIGABRT,
                            signal.SIGXCPU, signal.SIGXFSZ})


class StepFailed(Exception):
    def __init__(self, message: str, retryable: bool) -> None:
        super().__init__(message)
        self.retryable = retryable


def _log_message(log: Path, prefix: str = "") -> Optional[str]:
    """The last ``error: PREFIX...`` line of a step's log without that prefix; with no ``PREFIX`` and no error
    line, its last line; None when there is neither (or no log)."""
    try:
        lines = log.read_text(errors="replace").strip().splitlines()
    except OSError:
        return None
    errs = [ln for ln in lines if ln.startswith("error: " + prefix if prefix else "error:")]
    last = errs[-1] if errs else (lines[-1] if lines and not prefix else None)
    return None if last is None else last.removeprefix("error: ").removeprefix(prefix).strip()[:500]


def _children_cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _run(step: Step, args: list[str], job_dir: Path, module: str = "holo", *, append: bool = False,
         info: Optional[dict] = None) -> float:
    """Run ``python -m MODULE ARGS`` (default: holo) as a child (same process group) in an empty working folder
    (``args`` name files by absolute path); returns seconds taken. ``append``: add to the step's log (a step of
    several processes); ``info``: more for step.json (the parts of such a step)."""
    write_json_atomic(job_dir / "step.json", {"step": step, "index": STEPS.index(step), "t": time.time(),
                                              **(info or {})})
    t0 = time.monotonic()
    cpu0 = _children_cpu_s()
    mode = "ab" if append else "wb"
    with open(job_dir / f"{step}.log", mode) as log, tempfile.TemporaryDirectory(prefix=f"holo-{step}-") as cwd:
        # the CLI dies with the driver, however the driver dies (even SIGKILL, which no handler sees)
        proc = subprocess.run([sys.executable, "-m", module, *args], stdout=log, stderr=subprocess.STDOUT,
                              stdin=subprocess.DEVNULL, cwd=cwd, preexec_fn=_child_dies_with_driver)
    if proc.returncode != 0:
        try:
            with open(job_dir / f"{step}.log", "rb") as fh:
                fh.seek(max(0, fh.seek(0, os.SEEK_END) - 4000))
                tail = fh.read().decode(errors="replace")
        except OSError:
            tail = ""
        stopped = explain_limit(f"holo {step}", proc.returncode, tail, _children_cpu_s() - cpu0, current_limits())
        if stopped is not None:
            raise StepFailed(stopped, retryable=False)
        if proc.returncode < 0:
            sig = -proc.returncode
            if sig in _CRASH_SIGNALS:
                raise StepFailed(f"holo {step} crashed ({signal.Signals(sig).name}); the scene or options make it "
                                 "crash, so it is not retried", retryable=False)
            raise StepFailed(f"holo {step} was killed by signal {sig}", retryable=True)
        last = _log_message(job_dir / f"{step}.log")
        raise StepFailed(f"holo {step} failed (exit {proc.returncode}): {last or 'no message'}", retryable=False)
    return time.monotonic() - t0


def frames_zip(stack_path: Path, out: Path) -> int:
    """Write the stack's 8-bit frames as PNGs ``f{frame:03d}_c{color}.png`` into a zip; returns the count."""
    import numpy as np
    from PIL import Image

    from holocore.io import load_stack

    _, u8, _ = load_stack(stack_path)
    tmp = out.with_name(f".{out.name}.tmp")
    n = 0
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED) as zf:
        for f in range(u8.shape[0]):
            for c in range(u8.shape[1]):
                import io

                buf = io.BytesIO()
                Image.fromarray(np.ascontiguousarray(u8[f, c]), mode="L").save(buf, format="PNG")
                zf.writestr(f"f{f:03d}_c{c}.png", buf.getvalue())
                n += 1
    os.replace(tmp, out)
    return n


def preview_focus_mm(meta: dict) -> float:
    """Focus of the preview: the middle of the image volume in hologram space (linear in dioptres), mm
    (holocore.evaluate.scoring.focus_planes_m with one plane; z_inf without an analysis)."""
    from holocore.evaluate.scoring import focus_planes_m

    return focus_planes_m(meta, 1)[0] * 1e3


def _peak_rss_bytes() -> int:
    """The largest resident set of this driver or any step it ran (the job's measured peak memory)."""
    import resource

    kib = max(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,
              resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)
    return int(kib) * 1024


def write_options(spec: JobFile, job_dir: Path) -> None:
    """``job_dir/options.json``: the job's hologram options as one document (holocore.options.HologramOptions),
    which `holo render` and `holo encode` read whole (``--options-json``): no option is restated as a flag here."""
    write_json_atomic(job_dir / "options.json", spec.hologram_options().model_dump(mode="json"))


def write_render_plan(job_dir: Path) -> None:
    """``job_dir/plan.json``: the effect plan the render made (its summary and warnings), written as soon as the
    render ends, so a running job's page shows it through the later steps (and a job stopped after its render
    still has it). Only the result's meta member is read."""
    import numpy as np

    try:
        with np.load(job_dir / "result.npz", allow_pickle=False) as z:
            plan = json.loads(str(z["meta"])).get("plan") or {}
        write_json_atomic(job_dir / "plan.json", {"summary": list(plan.get("summary") or []),
                                                  "warnings": list(plan.get("warnings") or [])})
    except (OSError, ValueError, KeyError, AttributeError, TypeError):
        pass  # the page falls back on the plan render.log lists


def render_args(spec: JobFile, progress_path: str, job_dir: Path = Path(".")) -> list[str]:
    """The job's `holo render` command line (after ``holo``), its files in ``job_dir`` (``options.json``:
    :func:`write_options`)."""
    return ["render", spec.scene_path, "--out", str(job_dir / "result.npz"), "--optics-json",
            str(job_dir / "optics.json"), "--options-json", str(job_dir / "options.json"), "--progress-jsonl",
            progress_path]


def run_job(job_dir: Path) -> RunStatus:
    spec: JobFile = read_job_file(job_dir)
    timings: dict[str, float] = {}
    warnings: list[str] = []
    prog = {s: str(job_dir / f"progress-{s}.jsonl") for s in STEPS}
    write_options(spec, job_dir)
    timings["render_s"] = _run("render", render_args(spec, prog["render"], job_dir), job_dir)
    write_render_plan(job_dir)
    encode = ["encode", str(job_dir / "result.npz"), "--out", str(job_dir / "stack.npz"), "--options-json",
              str(job_dir / "options.json"), "--progress-jsonl", prog["encode"]]
    timings["encode_s"] = _run("encode", encode, job_dir)

    write_json_atomic(job_dir / "step.json", {"step": "package", "index": 2, "t": time.time()})
    t0 = time.monotonic()
    from holocore.io import file_sha256, load_stack

    phase, _, meta = load_stack(job_dir / "stack.npz")
    n = frames_zip(job_dir / "stack.npz", job_dir / "frames.zip")
    with open(prog["package"], "a") as fh:
        fh.write(json.dumps({"stage": "frames", "done": n, "total": n, "t": time.time()}) + "\n")
    timings["package_s"] = time.monotonic() - t0
    # the preview image and the web page's focal sweep and view grid (service/workers/pictures.py), in one
    # process that reads the stack once (its seconds: pictures_s)
    try:
        timings["pictures_s"] = _run("preview", [str(job_dir / "stack.npz"), "--out", str(job_dir / "pictures"),
                                                "--preview", str(job_dir / "preview.png"),
                                                "--preview-focus-mm", f"{preview_focus_mm(meta):.6f}",
                                                "--progress-jsonl", prog["preview"]], job_dir,
                                    module="service.workers.pictures")
    except StepFailed as exc:
        if exc.retryable:
            raise
        warnings.append(f"no pictures: {exc}")
    if not (job_dir / "preview.png").is_file():
        warnings.append("no preview: " + (_log_message(job_dir / "preview.log", "no preview: ")
                                          or "the step did not write it"))
    artifacts = {name: ArtifactInfo(sha256=file_sha256(job_dir / name), bytes=(job_dir / name).stat().st_size)
                 for name in ("stack.npz", "frames.zip", "preview.png") if (job_dir / name).is_file()}
    if spec.evaluate:  # the hologram stands without it: a failed evaluation is a warning unless it may be retried
        try:
            timings["evaluate_s"], more = run_evaluation(
                job_dir, scene_path=spec.scene_path, meta=meta, shape_fchw=tuple(phase.shape),
                stack_sha256=artifacts["stack.npz"].sha256, run=_run, failed=StepFailed)
            warnings += more
        except StepFailed as exc:
            if exc.retryable:
                raise
            warnings.append(f"no evaluation: {exc}")
        except (ValueError, OSError, KeyError, TypeError) as exc:
            warnings.append(f"no evaluation: {exc}")
    timings["peak_rss_bytes"] = _peak_rss_bytes()
    if not spec.keep_result:
        (job_dir / "result.npz").unlink(missing_ok=True)
    plan = meta.get("plan") or {}
    return RunStatus(ok=True, stack_sha256=artifacts["stack.npz"].sha256, stack_bytes=artifacts["stack.npz"].bytes,
                     shape_fchw=list(phase.shape), artifacts=artifacts, timings=timings,
                     plan={"summary": plan.get("summary", []), "plan": plan, "render_timings": meta.get("timings")},
                     warnings=warnings)


def _apply_limits(job_dir: Path) -> None:
    """Lower this driver's resource limits to what ``job.json`` says (the steps inherit them); a job file
    without them (written before they were) runs under the limits the driver was started with."""
    try:
        doc = json.loads((job_dir / "job.json").read_text()).get("limits")
    except (OSError, ValueError, AttributeError):
        return  # run_job reports the missing or broken job file
    if doc is not None:
        ProcessLimits.model_validate(doc).apply()


def main(argv: Optional[list[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("job_dir", type=Path)
    ap.add_argument("--parent-pid", type=int, default=None)
    args = ap.parse_args(argv)
    signal.signal(signal.SIGTERM, _on_term)
    _die_with_parent(args.parent_pid)
    job_dir = args.job_dir.resolve()
    t0 = time.time()
    try:
        _apply_limits(job_dir)
        status = run_job(job_dir)
        code = 0
    except StepFailed as exc:
        status = RunStatus(ok=False, error=str(exc), retryable=exc.retryable)
        code = EXIT_RETRY if exc.retryable else EXIT_FAILED
    except Exception as exc:  # noqa: BLE001 - report anything else as a failure of this run
        status = RunStatus(ok=False, error=f"worker error: {type(exc).__name__}: {exc}"[:1000], retryable=False)
        code = EXIT_FAILED
    try:  # which run this is: a stale run (after a restart) must not pass for the current one
        attempt = json.loads((job_dir / "job.json").read_text()).get("attempt")
    except (OSError, ValueError, AttributeError):
        attempt = None
    # uid: who ran it (a sandbox slot's uid when the service sandboxes jobs)
    doc = {**status.to_json(), "total_s": time.time() - t0, "uid": os.getuid(), "attempt": attempt,
           "limits": current_limits().model_dump(exclude_none=True)}  # what the run was held to
    write_json_atomic(job_dir / "status.json", doc)
    return code


if __name__ == "__main__":
    sys.exit(main())
