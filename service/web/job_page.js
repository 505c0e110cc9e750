// A job's page: its facts, progress with what is left, cancel, delete and re-run, the effect plan its own render
// made, timings, the steps' logs, downloads, and what the hologram looks like (focal sweep, view grid).

import { blobURL, getJSON, request, streamEvents } from "./api.js";
import { $, clear, el, fmtBytes, fmtSeconds, fmtTime, setText } from "./dom.js";
import { offerCompare } from "./compare.js";
import { resetEvaluation, showEvaluation } from "./evaluation.js";
import { offerSend, resetPhaseFrames, showPhaseFrames } from "./phase_frames.js";
import { actualSeconds, eta, jobName, loadText, lowQualityFlag, noEvaluation, pct } from "./job_facts.js";
import { renderLive } from "./job_live.js";
import { sceneName } from "./jobs_list.js";
import { clearJobPicture, showJobPicture } from "./scene_picture.js";
import { FINAL, aborted, plural, show, state, status } from "./state.js";

export function leaveJobPage() {
  if (!state.page) return;
  state.page.abort.abort();
  for (const u of state.page.urls) URL.revokeObjectURL(u);
  state.page = null;
}

function keep(url) { if (state.page) state.page.urls.push(url); return url; }

function fact(dl, term, value) { dl.append(el("dt", {}, term), el("dd", {}, value)); }

// The plan the job's own render made (stored when it ends; while it runs and after it stopped, its live view's,
// from the render's own plan file or log). A queued job holds only its scene's plan at the scene's default optics,
// which is not this job's (other frames, resolution, recording planes), so that is never shown as its plan: its
// live view's plan at the job's own options is, said to be that.
function ownPlan(job, live) {
  if (job.plan && !job.plan.source) return job.plan;
  return live && live.plan && live.plan.source === "render" ? live.plan : null;
}

function planNote(job, live) {
  if (live && live.plan && live.plan.source !== "render" && !FINAL.has(job.state)) {
    return "At this job's options, from its scene's plan; the render makes its own (and places the recording planes) "
      + "when it starts.";
  }
  if (FINAL.has(job.state)) return job.state === "succeeded" ? "The render recorded no plan."
    : `No effect plan: the job ${job.state === "failed" ? "failed" : "was cancelled"} before its render made one.`;
  return "The effect plan at this job's options comes when it renders.";
}

function renderJob(job) {
  const live = state.page && state.page.id === job.id ? state.page.live : null;
  setText($("job-id"), job.id);
  setText($("job-name-title"), jobName(job));
  const dl = clear($("job-facts"));
  const est = job.estimate || {};
  const t = job.timings || {};
  const actual = actualSeconds(job, live);
  fact(dl, "State", el("span", { class: `badge ${job.state}`, id: "job-state" }, job.state));
  const low = lowQualityFlag(job, true);
  if (low) { low.id = "job-quality-flag"; fact(dl, "Result", low); }
  // the sweep that made the job (GET /v1/jobs/{id} names it; the stream's updates do not repeat it)
  const sweepId = job.sweep_id || (state.page && state.page.id === job.id ? state.page.sweepId : null);
  if (sweepId) {
    fact(dl, "Sweep", el("a", { href: `#/sweeps/${sweepId}`, id: "job-sweep-link" }, `made by the sweep ${sweepId}`));
  }
  const sc = state.scenes.get(job.scene_id);
  fact(dl, "Scene", sc ? `${sc.entry} (${job.scene_id})` : job.scene_id);
  fact(dl, "Display", job.display || "–");
  const o = job.options || {};
  const optics = o.optics || {};
  fact(dl, "Options", `${(optics.resolution_hw || []).join("x")} px, ${plural(optics.frames, "frame")}, `
    + `${plural((optics.wavelengths_nm || []).length, "color")}, preset ${o.preset}, encoder ${o.encoder}`
    + (o.render_time_limit_s ? `, rendered for ${fmtSeconds(o.render_time_limit_s)}` : "")
    + (o.spp ? `, ${o.render_time_limit_s ? "at most " : ""}${plural(o.spp, "ray")} per pixel` : "")
    + (!o.evaluate ? "" : noEvaluation(job) ? ", no evaluation against ground truth (see below)"
      : job.state === "succeeded" ? ", evaluated against ground truth" : ", to be evaluated against ground truth"));
  fact(dl, "Time", `estimated ${loadText(est) || fmtSeconds(est.seconds)} (${est.model || "–"}), actual `
    + `${actual === null ? "–" : fmtSeconds(actual)}${t.reused ? " (reused an earlier result)" : ""}`);
  const q = est.quality;
  if (q && typeof q.psnr_db === "number") fact(dl, "Quality", el("span", { id: "job-quality" },
    `predicted ${Math.round(q.psnr_db)} dB ±${q.uncertainty_db} viewer-faithful PSNR`
    + (typeof q.target_db === "number" ? ` (options chosen for a target of ${q.target_db} dB)` : "")
    + ((q.warnings || []).length ? ` · ${q.warnings.join(" · ")}` : "")));
  fact(dl, "Memory", `estimated peak ${fmtBytes((est.memory || {}).peak_bytes)} (${(est.memory || {}).peak_stage || "–"}), `
    + `measured peak ${fmtBytes(t.peak_rss_bytes)}`);
  if (typeof t.engine === "string") fact(dl, "Ran on", `the ${t.engine} engine${job.attempts > 1 ? `, attempt ${job.attempts}` : ""}`);
  fact(dl, "Created", fmtTime(job.created_at));
  if (job.finished_at) fact(dl, "Finished", fmtTime(job.finished_at));
  if (job.reused_from) fact(dl, "Reused from", el("a", { href: `#/jobs/${job.reused_from}` }, job.reused_from));
  const p = pct(job);
  $("job-bar").style.width = `${(100 * p).toFixed(1)}%`;
  $("job-bar").dataset.fraction = String(p);
  const left = eta(job, live);
  // a queued job's time left already says it waits for a worker: that line alone, once
  setText($("job-stage"), FINAL.has(job.state) ? "" : `${Math.round(100 * p)}% · ${job.progress ? job.progress.step + " / "
    + job.progress.stage : left && job.state === "queued" ? left : "waiting for a worker"}`
    + (left && job.state === "running" ? " · " + left : ""));
  setText($("job-error"), job.error ? `Failed: ${job.error}` : "");
  renderActions(job);

  const plan = clear($("plan"));
  const own = ownPlan(job, live);
  const lines = (own && own.summary) || (!FINAL.has(job.state) && live && live.plan && live.plan.summary) || [];
  for (const line of lines) plan.append(el("li", {}, line));
  plan.dataset.source = own ? "render" : lines.length ? "options" : "";
  if (!own) plan.append(el("li", { class: "muted", id: "plan-note" }, planNote(job, live)));
  const warns = clear($("warnings"));
  const noEval = noEvaluation(job);  // said once, in the evaluation's card
  for (const w of (own && own.warnings) || (job.plan && job.plan.warnings) || []) {
    if (w !== noEval) warns.append(el("li", {}, w));
  }

  const tb = clear($("timings").tBodies[0]);
  for (const [k, v] of Object.entries(t)) {
    if (k === "peak_rss_bytes" || typeof v !== "number" || !k.endsWith("_s")) continue;
    tb.append(el("tr", {}, el("td", {}, k.replace(/_s$/, "")), el("td", { class: "num" }, v.toFixed(2))));
  }
  const none = !tb.firstChild;
  $("timings").hidden = none;
  setText($("timings-note"), !none ? "" : t.reused ? "Reused an earlier result: nothing ran."
    : job.state === "queued" ? "Nothing has run yet."
    : job.state === "running" ? "The run's own timings come when it finishes (the steps above are timed as it runs)."
    : `No step timings: the job ${job.state === "failed" ? "failed" : "was cancelled"} before it finished.`);
  renderDownloads(job);
  renderLive(live);
}

// The job's live view (what it is doing: plan, steps, worker, log tail), fetched at once; the stream then sends it.
async function fetchLive(page) {
  try {
    page.live = await getJSON(`/v1/jobs/${encodeURIComponent(page.id)}/live`, { signal: page.abort.signal });
  } catch (err) { if (aborted(err)) throw err; }
}

function renderActions(job) {
  const may = !!(state.me && state.me.may_submit);
  show("job-cancel", may && !FINAL.has(job.state));
  show("job-delete", may && FINAL.has(job.state));
  show("job-rerun", may);
  $("job-cancel").onclick = async () => {
    $("job-cancel").disabled = true;
    try {
      const done = await (await request(`/v1/jobs/${encodeURIComponent(job.id)}`, { method: "DELETE" })).json();
      if (state.page && state.page.id === job.id) renderJob(done);
    } catch (err) { status(`Not cancelled: ${err.message}`, true); }
    $("job-cancel").disabled = false;
  };
  const del = $("job-delete");
  if (!del.dataset.armed) setText(del, "Delete job");
  del.onclick = async () => {
    // two clicks: the first one arms the button for a few seconds (no modal dialog to get in the way)
    if (!del.dataset.armed) {
      del.dataset.armed = "1";
      setText(del, "Click again to delete the job and its files");
      setTimeout(() => { delete del.dataset.armed; setText(del, "Delete job"); }, 5000);
      return;
    }
    delete del.dataset.armed;
    del.disabled = true;
    try {
      await request(`/v1/jobs/${encodeURIComponent(job.id)}/delete`, { method: "POST" });
      state.jobs.delete(job.id);
      status(`Deleted job ${jobName(job)}.`);
      location.hash = "#/";
    } catch (err) { status(`Not deleted: ${err.message}`, true); }
    del.disabled = false;
    setText(del, "Delete job");
  };
  $("job-rerun").onclick = () => { state.rerunPending = job; location.hash = "#/"; };
}


// The steps' logs: a button per log, the chosen one's text below (the failing step's first on a failed job).
async function showLogs(job, page) {
  let logs;
  try {
    ({ logs } = await getJSON(`/v1/jobs/${encodeURIComponent(job.id)}/logs`, { signal: page.abort.signal }));
  } catch (err) { if (aborted(err)) throw err; logs = []; }
  if (state.page !== page) return;
  const tabs = clear($("log-tabs"));
  show("logs-card", logs.length > 0);
  if (!logs.length) return;
  const open = async (entry, button) => {
    for (const b of tabs.querySelectorAll("button")) b.classList.toggle("active", b === button);
    try {
      const text = await (await request(entry.url, { signal: page.abort.signal })).text();
      if (state.page === page) { setText($("log-text"), text || "(empty)"); $("log-text").dataset.step = entry.step; }
    } catch (err) { if (!aborted(err) && state.page === page) setText($("log-text"), `Could not read the log: ${err.message}`); }
  };
  let first = null, ran = null;
  const stepAt = page.live && page.live.steps ? (page.live.steps.find((s) => s.state === "stopped") || {}).step : null;
  for (const entry of logs) {
    const b = el("button", { type: "button", class: "small", "data-step": entry.step }, `${entry.step}.log (${fmtBytes(entry.bytes)})`);
    b.addEventListener("click", () => open(entry, b));
    tabs.append(b);
    // the last step that ran with something in its log (the failing one on a failed job), the step the job
    // stopped at first
    if (entry.step !== "driver" && entry.bytes > 0) first = [entry, b];
    if (entry.step === stepAt && entry.bytes > 0) ran = [entry, b];
  }
  delete $("log-text").dataset.live;
  if (ran || first) await open(...(ran || first));
  else setText($("log-text"), "");
}

function renderDownloads(job) {
  const box = clear($("job-downloads"));
  if (job.state !== "succeeded") return;
  const files = [["stack", "stack.npz", `${job.id}-stack.npz`], ["frames", "frames.zip", `${job.id}-frames.zip`],
                 ["preview", "preview.png", `${job.id}-preview.png`]];
  for (const [key, label, name] of files) {
    if (!job.links[key]) continue;
    const b = el("button", { type: "button", class: "download", "data-file": label }, `Download ${label}`);
    b.addEventListener("click", async () => {
      b.disabled = true;
      try {
        const url = await blobURL(job.links[key]);
        const a = el("a", { href: url, download: name });
        document.body.append(a); a.click(); a.remove();
        setTimeout(() => URL.revokeObjectURL(url), 60000);
      } catch (err) { status(`Download failed: ${err.message}`, true); }
      b.disabled = false;
    });
    box.append(b);
  }
  if (job.stack_sha256) box.append(el("span", { class: "mono muted" }, ` stack sha256 ${job.stack_sha256.slice(0, 16)}…`));
}

// Everything one job's page shows, emptied: the next job (or a missing one) starts from nothing.
function resetJobPage() {
  for (const id of ["job-facts", "job-downloads", "plan", "warnings", "log-tabs", "grid"]) clear($(id));
  clear($("timings").tBodies[0]);
  clear($("steps")); delete $("log-text").dataset.live;
  for (const id of ["job-id", "job-name-title", "job-stage", "job-worker", "job-error", "look-note", "timings-note",
                    "log-text", "focus-label", "grid-label"]) setText($(id), "");
  $("job-bar").style.width = "0"; $("job-bar").dataset.fraction = "0";
  $("sweep-img").removeAttribute("src"); $("preview-img").removeAttribute("src");
  for (const id of ["look", "logs-card", "job-cancel", "job-delete", "job-rerun", "job-compare"]) show(id, false);
  clearJobPicture();
  resetPhaseFrames();
  resetEvaluation();
}

export async function showJob(id) {
  leaveJobPage();
  const page = { id, abort: new AbortController(), urls: [], live: null };
  state.page = page;
  resetJobPage();
  let job;
  try {
    job = await getJSON(`/v1/jobs/${id}`, { signal: page.abort.signal });
  } catch (err) {
    if (aborted(err) || state.page !== page) return;
    // nothing of a job to show: only the address asked for and why
    setText($("job-id"), id);
    setText($("job-name-title"), err.status === 404 ? "not found" : "");
    setText($("job-error"), err.status === 404 ? `No such job (or it is another owner's): ${id} was not found.`
      : `Could not load the job: ${err.message}`);
    show("timings-card", false); show("plan-card", false);
    return;
  }
  show("timings-card", true); show("plan-card", true);
  page.sweepId = job.sweep_id || null;
  await sceneName(job.scene_id);
  if (state.page !== page) return;
  await fetchLive(page);
  if (state.page !== page) return;
  renderJob(job);
  showJobPicture(job, page.abort.signal).catch(() => {});
  if (!FINAL.has(job.state)) {
    try {
      await streamEvents(`/v1/jobs/${id}/events`, (name, data) => {
        if (name === "state") job = data;
        else if (name === "progress") job = { ...job, state: data.state, progress: data };
        else if (name === "live") page.live = data;
        renderJob(job);
      }, page.abort.signal);
    } catch (_) { if (page.abort.signal.aborted) return; }
    if (state.page !== page) return;
    job = await getJSON(`/v1/jobs/${id}`, { signal: page.abort.signal });
    if (state.page !== page) return;
    await fetchLive(page);
    if (state.page !== page) return;
    renderJob(job);
  }
  await showLogs(job, page);
  if (state.page !== page) return;
  if (job.state === "succeeded") {
    offerCompare(job, page.abort.signal).catch((err) => { if (!aborted(err)) $("job-compare").hidden = true; });
    showPhaseFrames(job, page).catch((err) => { if (!aborted(err)) status(`No phase frames: ${err.message}`, true); });
    offerSend(job, page).catch((err) => { if (!aborted(err)) status(`Displays: ${err.message}`, true); });
    await showPictures(job, page);
    if (state.page !== page) return;
    await showEvaluation(job, page).catch((err) => { if (!aborted(err)) setText($("eval-note"), err.message); });
  }
}

async function showPictures(job, page) {
  show("look", true);
  try {
    const pv = keep(await blobURL(job.links.preview, { signal: page.abort.signal }));
    if (state.page === page) $("preview-img").src = pv;
  } catch (_) { $("preview-img").alt = "no preview"; }
  let idx;
  try {
    idx = await getJSON(`/v1/jobs/${job.id}/pictures`, { signal: page.abort.signal });
  } catch (err) {
    setText($("look-note"), err.message);
    return;
  }
  if (state.page !== page) return;
  const sweep = idx.sweep.pictures;
  const urls = await Promise.all(sweep.map((p) => blobURL(p.url, { signal: page.abort.signal }).then(keep)));
  if (state.page !== page) return;
  const slider = $("focus");
  slider.max = String(sweep.length - 1);
  slider.value = String(Math.floor((sweep.length - 1) / 2));
  const showFocus = () => {
    const i = Number(slider.value);
    $("sweep-img").src = urls[i];
    $("sweep-img").dataset.index = String(i);
    setText($("focus-label"), `${sweep[i].z_mm.toFixed(3)} mm from the SLM (${sweep[i].words})`);
  };
  slider.oninput = showFocus;
  showFocus();
  setText($("look-note"), `Simulated reconstruction (${idx.shape_hw.join("x")} px, ${plural(idx.frames, "frame")} averaged): `
    + `focal sweep with a ${idx.sweep.pupil_mm} mm pupil, ${idx.sweep.order}`
    + (idx.sweep.widened ? ` (the scene is shallower than the eye's depth of field, `
      + `${idx.sweep.depth_of_field_mm} mm: the sweep spans ±3 depths of field)` : "") + ".");
  const grid = clear($("grid"));
  for (const p of idx.grid.pictures) {
    const url = keep(await blobURL(p.url, { signal: page.abort.signal }));
    if (state.page !== page) return;
    grid.append(el("img", { src: url, alt: `eye at ${p.offset_mm.join(", ")} mm`,
                            title: `eye at x ${p.offset_mm[0]} mm, y ${p.offset_mm[1]} mm` }));
  }
  setText($("grid-label"), `View grid: eye ${idx.grid.cols}x${idx.grid.rows} across a ${idx.grid.eye_box_mm} mm eye box `
    + `(${idx.grid.pupil_mm} mm pupil), focused at ${idx.grid.focus_mm} mm (${idx.grid.focus_words})`);
}
