"""`holo submit`: upload a scene to a running service, submit a job, show its progress, download the stack."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Optional

import typer

from holo.common import OpticsOptions, fail, hologram_options, with_optics_options
from holocore.options import MAX_WRP_PLANES


def register(app: typer.Typer) -> None:
    app.command("submit")(submit)


@with_optics_options
def submit(
    scene: Path = typer.Argument(..., help="Scene folder, .zip bundle, or the scene's .xml (its folder is sent)."),
    server: str = typer.Option(..., "--server", help="Service URL, e.g. http://127.0.0.1:8080"),
    token: Optional[str] = typer.Option(None, "--token", help="Bearer token (scopes submit); default $HOLO_TOKEN."),
    out: Optional[Path] = typer.Option(None, "--out", help="Where to write STACK.npz (omit: do not download)."),
    entry: Optional[str] = typer.Option(None, "--entry", help="Scene XML inside the bundle, when it holds several."),
    preset: Optional[str] = typer.Option(None, help="fast | balanced (default) | reference"),
    spp: Optional[int] = typer.Option(None, help="Rays per WRP pixel (default: from the preset; with "
                                                 "--time-limit-s, the most)."),
    max_spp: Optional[int] = typer.Option(None, "--max-spp", help="Without --spp: the most rays per WRP pixel the "
                                                                  "preset may choose (the service's cap still holds)."),
    time_limit_s: Optional[float] = typer.Option(None, "--time-limit-s", help="Render for about this many "
                                                 "seconds (rays until the time is spent)."),
    encoder: Optional[str] = typer.Option(None, help="sgd (default) | dpac"),
    optimiser: Optional[str] = typer.Option(None, help="sgd's steps: lbfgs (default, 28 iterations) | adam (until "
                                                       "its stop rule)."),
    iterations: Optional[int] = typer.Option(None, help="Encoder iterations (sgd; default: the optimiser's)."),
    method: Optional[str] = typer.Option(None, help="wrp (default) | direct"),
    wrp_planes: Optional[str] = typer.Option(
        None, "--wrp-planes", help=f"Wave recording planes: 1..{MAX_WRP_PLANES}, or auto "
                                   "(default: chosen from the scene depth)."),
    options_json: Optional[Path] = typer.Option(None, "--options-json", help="The hologram's options as one JSON "
                                                "document (docs/options.md); the flags above override it."),
    to_display: Optional[str] = typer.Option(None, "--to-display", help="The lab display the job is for (its "
                                                                        "agent picks the stack up)."),
    name: Optional[str] = typer.Option(None, "--name", help="A name for people (default: the service's, from the "
                                                            "scene)."),
    evaluate: bool = typer.Option(False, "--evaluate", help="Also score the hologram against Mitsuba thin-lens "
                                                          "ground truth on the service (GET "
                                                          "/v1/jobs/{id}/evaluation)."),
    quality_db: Optional[float] = typer.Option(None, "--quality-db", help="Aim at this viewer-faithful PSNR (dB, "
                                               "5..40): the service chooses frames, spp and iterations to reach it "
                                               "soonest (give it without them)."),
    idempotency_key: Optional[str] = typer.Option(None, "--idempotency-key", help="Repeat a submit safely."),
    no_wait: bool = typer.Option(False, "--no-wait", help="Print the job id and return at once."),
    *,
    optics: OpticsOptions,
) -> None:
    """Upload SCENE, submit a render job, follow its progress and download the stack. The optics options are
    `holo render`'s (--display names the optics profile, as there); --to-display names the lab display."""
    token = token or os.environ.get("HOLO_TOKEN")
    if not token:
        fail("give --token or set HOLO_TOKEN")
    if not scene.exists():
        fail(f"scene not found: {scene}")
    hopts = hologram_options(options_json, "submit", preset=preset, frames=optics.frames, spp=spp, max_spp=max_spp,
                             render_time_limit_s=time_limit_s, encoder=encoder, iterations=iterations,
                             optimiser=optimiser, method=method, wrp_planes=wrp_planes, quality_db=quality_db)
    _, cfg = optics.resolve()
    body = {"optics": cfg.model_dump(mode="json"), **hopts.model_dump(mode="json"), "display": to_display,
            "name": name, "evaluate": evaluate or None}
    body = {k: v for k, v in body.items() if v is not None}

    from rich.console import Console

    from service.client import ClientError, ServiceClient

    console = Console(stderr=True)
    try:
        client = ServiceClient(server, token=token)
    except ValueError as exc:
        fail(str(exc))
    try:
        with client:
            _submit_and_follow(client, console, scene, body, entry=entry, quality_db=quality_db,
                               idempotency_key=idempotency_key, no_wait=no_wait, out=out)
    except ClientError as exc:
        fail(str(exc), code=1)
    except Exception as exc:  # noqa: BLE001 - transport errors: one line, not a traceback
        import httpx

        if isinstance(exc, httpx.HTTPError):
            fail(f"{server}: {type(exc).__name__}: {exc}", code=1)
        raise


def _submit_and_follow(client, console, scene: Path, body: dict, *, entry: Optional[str],
                       quality_db: Optional[float], idempotency_key: Optional[str], no_wait: bool,
                       out: Optional[Path]) -> None:
    """Upload, say what the options buy, submit, then (unless ``no_wait``) follow the job and download."""
    sc = client.upload_scene(scene, entry=entry)
    console.print(f"scene {sc['id']} ({sc['report']['total_bytes']:,} bytes, {len(sc['report']['files'])} "
                  f"files, sha256 {sc['sha256'][:12]}..)")
    for w in sc["report"].get("warnings", []):
        console.print(f"  warning: {w}")
    _print_ahead(console, client.estimate({"scene_id": sc["id"], **body}), quality_db)
    job = client.submit({"scene_id": sc["id"], **body}, idempotency_key=idempotency_key)
    est = _estimate_words(job.get("estimate") or {})
    console.print(f"job {job['id']}: {job['state']}" + (f", estimated {est}" if est else "")
                  + (f" (reused {job['reused_from']})" if job.get("reused_from") else ""))
    if no_wait:
        print(job["id"])
        return
    final = _follow(client, console, job)
    if final["state"] != "succeeded":
        fail(f"job {final['id']} {final['state']}: {final.get('error') or 'no message'}", code=1)
    t = final.get("timings") or {}
    console.print(f"job {final['id']} succeeded" + (f" in {t['run_s']:.1f} s" if "run_s" in t else ""))
    if out is not None:
        digest = client.download_stack(final["id"], out)
        console.print(f"stack -> {out} (sha256 {digest[:16]}..)")
    print(json.dumps({"job_id": final["id"], "stack_sha256": final["stack_sha256"]}))


def _print_ahead(console, ahead: dict, quality_db: Optional[float]) -> None:
    """What the options buy, before they run: the predicted quality, a target's chosen options, warnings."""
    q = ahead["estimate"].get("quality") or {}
    if q:
        console.print(f"predicted quality: {q['words']}")
    if ahead.get("options"):
        o = ahead["options"]
        rays = o["spp"] or "the preset's"
        its = o["iterations"] or "the optimiser's default"
        console.print(f"  for {quality_db:g} dB the service chose {o['frames']} frames, {rays} rays per "
                      f"pixel, {its} encoder iterations")
    for w in ahead.get("warnings") or []:
        console.print(f"  warning: {w}")
    for line in q.get("instead") or []:
        console.print(f"  instead: {line}")


def _estimate_words(e: dict) -> Optional[str]:
    """The job's estimated time in words: at the machine's present load when that slows it, not an idle one's."""
    est, load = e.get("seconds"), e.get("load") or {}
    if est and load.get("slowdown", 1.0) >= 1.2:
        return (f"{e['seconds_at_load']:.0f} s at the machine's present load ({load['others']:.1f} other "
                f"threads on {load['cores']} cores), {est:.0f} s on an idle one")
    return f"{est:.0f} s" if est else None


def _follow(client, console, job: dict) -> dict:
    """Follow the job to its end with a progress bar; its final state. The fraction is weighed by the
    estimate's seconds per step, so the pace gives the time left (and carries the load the job meets)."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                  TimeElapsedColumn(), TimeRemainingColumn(), console=console, transient=True,
                  disable=not sys.stderr.isatty()) as bar:
        task = bar.add_task(job["state"], total=1.0)

        def on_event(event: str, data: dict) -> None:
            if event == "progress":
                bar.update(task, completed=float(data.get("fraction", 0.0)),
                           description=f"{data.get('step', '')}: {data.get('stage', '')}")
            elif event == "state":
                bar.update(task, description=data.get("state", ""))

        return client.follow(job["id"], on_event)
