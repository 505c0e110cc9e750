// The results page: sign in with a token, the job list with live progress, a submit form with the estimate and
// the effect plan at the chosen options, and a job page with the plan, timings, logs, downloads, cancel, delete
// and re-run, and what the hologram looks like (focal sweep, view grid).
// Everything the service says is shown with textContent (dom.js); nothing is parsed as HTML.

import { ApiError, blobURL, getJSON, postJSON, request, setUnauthorizedHandler, streamEvents, token } from "./api.js";
import { $, clear, el, fmtBytes, fmtSeconds, fmtTime, setText } from "./dom.js";

const FINAL = new Set(["succeeded", "failed", "cancelled"]);
const MAX_STREAMS = 4; // live event streams at once (a browser holds ~6 connections per host)

const state = {
  me: null,
  profiles: null,
  scenes: new Map(), // scene id -> scene (entry name for the lists)
  jobs: new Map(),
  streams: new Map(), // job id -> AbortController (job list streams)
  page: null, // {id, abort, urls}
  scene: null, // the scene uploaded in the form
  rerun: null, // the job whose options the form holds (re-run with changes)
  rerunPending: null, // the job the Re-run button asked for, taken by the next visit to the home page
  timer: null,
  shown: new Map(), // job id -> the largest fraction shown: progress never moves backwards on the page
  thumbs: new Map(), // job id -> object URL of its preview (the list's thumbnails)
};

const plural = (n, one, many = `${one}s`) => `${n} ${n === 1 ? one : many}`;
const aborted = (err) => err && err.name === "AbortError";

function status(text, isError = false) {
  const s = $("status");
  setText(s, text);
  s.classList.toggle("error", isError);
}

// ---- sign in / out -------------------------------------------------------------------------------------------
function show(id, visible) { $(id).hidden = !visible; }

function signedOut(message = "") {
  token.clear();
  state.me = null;
  stopAll();
  clearTimeout(estimateTimer); estimateSeq++;  // no estimate goes out after signing out, none comes back in
  show("signin", true); show("home", false); show("job", false); show("signout", false);
  setText($("who"), "");
  setText($("signin-error"), message);
  $("token").focus();
}

async function signIn(ev) {
  ev.preventDefault();
  const tok = $("token").value.trim();
  $("token").value = "";
  if (!tok) return;
  try {
    const me = await getJSON("/v1/whoami", { tok });
    token.set(tok);
    await start(me);
  } catch (err) {
    setText($("signin-error"), err instanceof ApiError && err.status === 401
      ? "That token is not valid (or it was revoked, or it expired)." : `Could not sign in: ${err.message}`);
  }
}

async function start(me) {
  state.me = me || await getJSON("/v1/whoami");
  setText($("who"), `${state.me.owner} · ${state.me.scopes.join(", ")}`);
  show("signin", false); show("signout", true);
  setText($("signin-error"), "");
  show("submit", !!state.me.may_submit);
  if (state.me.may_submit && !state.profiles) await loadProfiles();
  route();
}

// ---- routing --------------------------------------------------------------------------------------------------
function stopAll() {
  for (const c of state.streams.values()) c.abort();
  state.streams.clear();
  leaveJobPage();
  if (state.timer) { clearInterval(state.timer); state.timer = null; }
}

function route() {
  if (!state.me) return;
  const m = /^#\/jobs\/([A-Za-z0-9_-]{1,64})$/.exec(location.hash);
  stopAll();
  if (m) {
    show("home", false); show("job", true);
    showJob(m[1]).catch((err) => { if (!aborted(err)) status(`Could not show the job: ${err.message}`, true); });
  } else {
    show("job", false); show("home", true);
    refreshHome();
    state.timer = setInterval(refreshHome, 10000);
    const again = state.rerunPending;
    state.rerunPending = null;
    if (again) prefillRerun(again).catch((err) => status(`Could not re-run: ${err.message}`, true));
    else if (state.scene) estimateSoon();
  }
}

// ---- the job list ---------------------------------------------------------------------------------------------
async function sceneName(id) {
  if (state.scenes.has(id)) return state.scenes.get(id).entry;
  try {
    const sc = await getJSON(`/v1/scenes/${encodeURIComponent(id)}`);
    state.scenes.set(id, sc);
    return sc.entry;
  } catch (_) {
    return id;
  }
}

// The fraction shown for a job: the largest one shown so far (a step's progress file starting over, or a
// restarted stream, never moves the bar back); 1 once it has succeeded.
function pct(job) {
  if (job.state === "succeeded") return 1;
  const f = job.progress && typeof job.progress.fraction === "number" ? job.progress.fraction : 0;
  const p = Math.max(state.shown.get(job.id) || 0, Math.max(0, Math.min(1, f)));
  if (job.state === "running") state.shown.set(job.id, p);
  return p;
}

// What is left, from the estimate: its seconds less the time run so far, or (past the estimate) the time run so
// far scaled by the fraction still to do.
function eta(job) {
  const est = job.estimate && typeof job.estimate.seconds === "number" ? job.estimate.seconds : null;
  if (job.state === "queued") return est === null ? "waiting for a worker" : `waiting for a worker; about ${fmtSeconds(est)} once it starts`;
  if (job.state !== "running" || est === null || !job.started_at) return "";
  const ran = Math.max(0, (Date.now() - Date.parse(job.started_at)) / 1000);
  const p = pct(job);
  if (ran < est) return `about ${fmtSeconds(est - ran)} left`;
  if (p > 0.05) return `about ${fmtSeconds(ran * (1 - p) / p)} left (past the estimate of ${fmtSeconds(est)})`;
  return `past the estimate of ${fmtSeconds(est)}`;
}

function jobName(job) {
  if (job.name) return job.name;
  const sc = state.scenes.get(job.scene_id);
  return sc ? sc.entry : job.scene_id;
}

function optionsText(job) {
  const o = job.options || {};
  const optics = o.optics || {};
  const res = (optics.resolution_hw || []).join("x");
  return [res && `${res} px`, typeof optics.frames === "number" ? plural(optics.frames, "frame") : null,
          o.preset, o.encoder, o.render_time_limit_s ? `${fmtSeconds(o.render_time_limit_s)} limit` : null,
          o.spp && !o.render_time_limit_s ? `${o.spp} rays/px` : null].filter(Boolean).join(" · ");
}

function actualSeconds(job) {
  const t = job.timings || {};
  if (typeof t.run_s === "number") return t.run_s;
  if (job.state === "running" && job.started_at) return (Date.now() - Date.parse(job.started_at)) / 1000;
  return null;
}

function estimateCells(job) {
  const est = job.estimate || {};
  const mem = est.memory || {};
  const t = job.timings || {};
  const actual = actualSeconds(job);
  const reused = t.reused ? " (reused)" : "";
  return [
    el("td", { class: "num" }, `${fmtSeconds(est.seconds)} / ${actual === null ? "–" : fmtSeconds(actual)}${reused}`),
    el("td", { class: "num" }, `${fmtBytes(mem.peak_bytes)} / ${fmtBytes(t.peak_rss_bytes)}`),
  ];
}

function progressCell(job) {
  const p = pct(job);
  const stage = job.progress && job.progress.stage ? job.progress.stage : "";
  const left = eta(job);
  return el("td", { class: "progress-cell" },
    el("progress", { max: "1", value: String(p) }),
    el("span", { class: "muted" }, ` ${Math.round(100 * p)}%${stage && !FINAL.has(job.state) ? " " + stage : ""}`),
    left ? el("div", { class: "muted eta" }, left) : null);
}

function thumbCell(job) {
  const td = el("td", { class: "thumb" });
  const url = state.thumbs.get(job.id);
  if (url) td.append(el("img", { src: url, alt: "preview", class: "thumb" }));
  return td;
}

function jobRow(job) {
  const scene = state.scenes.has(job.scene_id) ? state.scenes.get(job.scene_id).entry : job.scene_id;
  return el("tr", { "data-job-id": job.id, class: `state-${job.state}` },
    thumbCell(job),
    el("td", { class: "job-name" }, el("a", { href: `#/jobs/${job.id}` }, jobName(job)),
       el("div", { class: "mono muted" }, job.id)),
    el("td", { class: "scene-name", title: job.scene_id }, scene),
    el("td", { class: "options" }, optionsText(job)),
    el("td", {}, job.display || "–"),
    el("td", { class: "state" }, el("span", { class: `badge ${job.state}` }, job.state),
       job.error ? el("div", { class: "error reason" }, job.error) : null),
    progressCell(job),
    ...estimateCells(job),
    el("td", {}, fmtTime(job.created_at)));
}

// Thumbnails of the newest succeeded jobs' previews (fetched once each; blob: URLs, as every picture here).
async function loadThumbs(jobs) {
  const want = jobs.filter((j) => j.state === "succeeded" && j.links.preview && !state.thumbs.has(j.id)).slice(0, 24);
  for (const j of want) {
    try {
      state.thumbs.set(j.id, await blobURL(j.links.preview));
      const row = $("jobs").tBodies[0].querySelector(`tr[data-job-id="${CSS.escape(j.id)}"]`);
      if (row) row.replaceWith(jobRow(state.jobs.get(j.id) || j));
    } catch (_) { state.thumbs.set(j.id, null); }
  }
}

function updateRow(job) {
  state.jobs.set(job.id, job);
  const body = $("jobs").tBodies[0];
  const old = body.querySelector(`tr[data-job-id="${CSS.escape(job.id)}"]`);
  const row = jobRow(job);
  if (old) old.replaceWith(row); else body.prepend(row);
}

async function refreshHome() {
  try {
    const { jobs } = await getJSON("/v1/jobs?limit=100");
    await Promise.all([...new Set(jobs.map((j) => j.scene_id))].map(sceneName));
    const body = clear($("jobs").tBodies[0]);
    for (const j of jobs) { state.jobs.set(j.id, j); body.append(jobRow(j)); }
    show("jobs-empty", jobs.length === 0);
    for (const j of jobs) if (!FINAL.has(j.state)) follow(j.id);
    loadThumbs(jobs);
    await refreshDisplays();
    if ($("status").classList.contains("error")) status("");  // an earlier load's failure is over
  } catch (err) {
    if (!(err instanceof ApiError && err.status === 401)) status(`Could not load the jobs: ${err.message}`, true);
  }
}

function follow(id) {
  if (state.streams.has(id) || state.streams.size >= MAX_STREAMS) return;
  const ctl = new AbortController();
  state.streams.set(id, ctl);
  streamEvents(`/v1/jobs/${id}/events`, (name, data) => {
    const job = state.jobs.get(id) || {};
    if (name === "state") updateRow(data);
    else if (name === "progress") updateRow({ ...job, state: data.state, progress: data });
  }, ctl.signal).catch(() => {}).finally(async () => {
    state.streams.delete(id);
    if (ctl.signal.aborted) return;
    try { updateRow(await getJSON(`/v1/jobs/${id}`)); } catch (_) { /* gone */ }
    for (const j of state.jobs.values()) if (!FINAL.has(j.state)) follow(j.id);
  });
}

async function refreshDisplays() {
  const { displays } = await getJSON("/v1/displays");
  const body = clear($("displays").tBodies[0]);
  for (const d of displays) {
    const showing = d.showing ? `${d.showing.job_id} frame ${d.showing.frame}` : "–";
    body.append(el("tr", {},
      el("td", {}, d.name), el("td", {}, d.owner || "–"), el("td", {}, d.state || "–"),
      el("td", { class: "mono" }, showing), el("td", { class: "message" }, d.message || ""),
      el("td", {}, `${fmtSeconds(d.age_s)} ago`)));
  }
  show("displays-empty", displays.length === 0);
}

// ---- the submit form ------------------------------------------------------------------------------------------
async function loadProfiles() {
  state.profiles = await getJSON("/v1/display-profiles");
  const sel = clear($("profile"));
  for (const p of state.profiles.profiles) {
    sel.append(el("option", { value: p.name, title: p.description }, `${p.name} (${p.optics.resolution_hw.join("x")}, `
      + `${p.optics.pitch_um} µm, ${p.optics.wavelengths_nm.length} colors)`));
  }
  sel.value = state.profiles.default;
  applyProfile();
}

function profile() {
  const v = $("profile").value;
  if (state.rerun && v === `job:${state.rerun.id}`) return { name: v, optics: state.rerun.options.optics };
  return state.profiles.profiles.find((p) => p.name === v) || state.profiles.profiles[0];
}

function applyProfile() {
  const o = profile().optics;
  $("res-h").value = o.resolution_hw[0];
  $("res-w").value = o.resolution_hw[1];
  $("frames").value = Math.min(o.frames, 64);
}

function jobBody() {
  const o = { ...profile().optics };
  delete o.frames;
  o.resolution_hw = [Number($("res-h").value), Number($("res-w").value)];
  const body = { scene_id: state.scene.id, optics: o, preset: $("preset").value, frames: Number($("frames").value),
                 encoder: $("encoder").value };
  if ($("spp").value) body.spp = Number($("spp").value);
  if ($("iterations").value && body.encoder === "sgd") body.iterations = Number($("iterations").value);
  if ($("time-limit").value) body.render_time_limit_s = Number($("time-limit").value);
  const planes = $("wrp-planes").value;
  body.wrp_planes = planes === "auto" ? "auto" : Number(planes);
  if ($("display").value.trim()) body.display = $("display").value.trim();
  if ($("job-name").value.trim()) body.name = $("job-name").value.trim();
  return body;
}

// The form's state goes with the scene it was made for: a new upload (refused or not) takes the old one away
// first, so Submit can never send the previous scene.
function forgetScene() {
  state.scene = null;
  state.rerun = null;
  estimateSeq++; clearTimeout(estimateTimer);
  show("job-form", false); show("rerun-note", false); show("form-plan-box", false);
  $("submit-button").disabled = true;
  setText($("estimate"), ""); setText($("submit-error"), "");
  const sel = $("profile");
  for (const o of [...sel.options]) if (o.value.startsWith("job:")) o.remove();
  if (!sel.value && state.profiles) { sel.value = state.profiles.default; applyProfile(); }
}

function nameFromFile(file) { return file ? file.name.replace(/\.zip$/i, "").slice(0, 120) : ""; }

async function upload(ev) {
  ev.preventDefault();
  const file = $("bundle").files[0];
  if (!file) return;
  const fd = new FormData();
  fd.append("bundle", file, "bundle.zip");
  if ($("entry").value.trim()) fd.append("entry", $("entry").value.trim());
  $("upload-button").disabled = true;
  forgetScene();
  const info = clear($("scene-info"));
  info.append(el("p", { class: "muted" }, "Uploading and checking the bundle…"));
  try {
    const sc = await (await request("/v1/scenes", { method: "POST", body: fd })).json();
    state.scene = sc;
    state.scenes.set(sc.id, sc);
    showScene(sc);
    $("job-name").value = nameFromFile(file);
    show("job-form", true);
    estimateSoon();
    waitForPlan(sc.id);
  } catch (err) {
    const why = String(err.message).replace(/^scene refused:\s*/i, "");
    clear(info).append(el("p", { class: "error", id: "scene-error" }, `Scene refused: ${why}`));
  } finally {
    $("upload-button").disabled = false;
  }
}

function showScene(sc) {
  const r = sc.report || {};
  const info = clear($("scene-info"));
  info.append(
    el("p", {}, "Scene ", el("strong", { id: "scene-entry" }, sc.entry), " ",
       el("span", { class: "mono muted" }, sc.id)),
    el("p", { class: "muted" }, `${(r.files || []).length} files, ${fmtBytes(r.total_bytes)}; plugins: `
       + `${(r.plugins || []).join(", ") || "–"}; effect plan: ${sc.plan_state}`));
  for (const w of [...(r.warnings || []), ...(r.ignored || [])]) info.append(el("p", { class: "warning" }, String(w)));
  if (sc.plan_error) info.append(el("p", { class: "error" }, sc.plan_error));
}

// Follows the form's scene until its plan is ready or has failed, however long the planner's queue is (a
// failed request is tried again); Submit waits for it.
async function waitForPlan(id) {
  for (let i = 0; ; i++) {
    await new Promise((r) => setTimeout(r, i < 30 ? 1000 : 3000));
    if (!state.scene || state.scene.id !== id || !state.me) return;
    try {
      const sc = await getJSON(`/v1/scenes/${id}`);
      if (!state.scene || state.scene.id !== id) return;
      if (sc.plan_state !== state.scene.plan_state) {
        state.scene = sc; state.scenes.set(id, sc); showScene(sc); estimateSoon();
      }
      if (sc.plan_state === "ready" || sc.plan_state === "failed") return;
    } catch (err) { if (err instanceof ApiError && (err.status === 401 || err.status === 404)) return; }
  }
}

// A job may only be submitted on a scene Mitsuba has loaded: until its plan is ready the scene may still fail
// (a job on it would fail with it), so Submit waits for the plan.
const planReady = () => !!state.scene && state.scene.plan_state === "ready";

let estimateTimer = null;
let estimateSeq = 0;
function estimateSoon() {
  $("submit-button").disabled = true;
  clearTimeout(estimateTimer);
  estimateTimer = setTimeout(estimate, 250);
}

// Boxes that must hold something (their label's words); every other check is the server's, whose refusal says
// what to change (the browser's own range checks would only say "invalid").
const REQUIRED = [["frames", "Frames"], ["res-h", "Resolution (rows)"], ["res-w", "Resolution (columns)"]];

function showFormPlan(plan) {
  const ul = clear($("form-plan"));
  for (const line of (plan && plan.summary) || []) ul.append(el("li", {}, line));
  show("form-plan-box", !!ul.firstChild);
}

async function estimate() {
  if (!state.scene) return;
  const seq = ++estimateSeq;
  const out = $("estimate");
  setText($("submit-error"), "");
  out.classList.remove("error");
  const empty = REQUIRED.filter(([id]) => !$(id).value.trim()).map(([, words]) => words);
  if (empty.length) { setText(out, `Fill in ${empty.join(", ")} to see the estimate.`); return; }
  if (state.scene.plan_state === "failed") {
    setText(out, "Cannot submit: the scene's plan failed (see above); fix the scene and upload it again.");
    out.classList.add("error"); showFormPlan(null);
    return;
  }
  try {
    const e = await postJSON("/v1/jobs/estimate", jobBody());
    if (seq !== estimateSeq || !state.scene) return;
    const m = e.estimate.memory || {};
    const rays = e.estimate.spp_assumed === null ? "rays until the time limit"
      : `${e.estimate.spp_assumed} rays per pixel`;
    setText(out, `Estimate: ${fmtSeconds(e.estimate.seconds)} (${e.estimate.model}; ${rays}), peak memory ${fmtBytes(m.peak_bytes)} in ${m.peak_stage || "–"} of ${fmtBytes(e.worker_memory_bytes)}`
      + (e.reuses ? `; the result of job ${e.reuses} would be reused at once` : ""));
    out.classList.remove("error");
    showFormPlan(e.plan);
    if (!planReady()) out.append(el("span", { class: "muted", id: "plan-wait" },
      " · Submit waits for the scene's plan (Mitsuba loading the scene)…"));
    $("submit-button").disabled = !planReady();
  } catch (err) {
    if (seq !== estimateSeq) return;
    setText(out, `Cannot submit: ${err.message}`);
    out.classList.add("error");
    showFormPlan(null);
  }
}

async function submit(ev) {
  ev.preventDefault();
  if (!planReady() || $("submit-button").disabled) return;  // only what the estimate just accepted goes out
  $("submit-button").disabled = true;
  try {
    const resp = await request("/v1/jobs", { method: "POST", json: jobBody() });
    const job = await resp.json();
    state.jobs.set(job.id, job);
    location.hash = `#/jobs/${job.id}`;
  } catch (err) {
    setText($("submit-error"), `Not submitted: ${err.message}`);
    $("submit-button").disabled = false;
  }
}

// ---- the job page ---------------------------------------------------------------------------------------------
function leaveJobPage() {
  if (!state.page) return;
  state.page.abort.abort();
  for (const u of state.page.urls) URL.revokeObjectURL(u);
  state.page = null;
}

function keep(url) { if (state.page) state.page.urls.push(url); return url; }

function fact(dl, term, value) { dl.append(el("dt", {}, term), el("dd", {}, value)); }

// The plan the job's own render made; a queued job holds only its scene's plan at the scene's default optics,
// which is not this job's (other frames, resolution, recording planes), so that is never shown as its plan.
function ownPlan(job) { return job.plan && !job.plan.source ? job.plan : null; }

function renderJob(job) {
  setText($("job-id"), job.id);
  setText($("job-name-title"), jobName(job));
  const dl = clear($("job-facts"));
  const est = job.estimate || {};
  const t = job.timings || {};
  const actual = actualSeconds(job);
  fact(dl, "State", el("span", { class: `badge ${job.state}`, id: "job-state" }, job.state));
  const sc = state.scenes.get(job.scene_id);
  fact(dl, "Scene", sc ? `${sc.entry} (${job.scene_id})` : job.scene_id);
  fact(dl, "Display", job.display || "–");
  const o = job.options || {};
  const optics = o.optics || {};
  fact(dl, "Options", `${(optics.resolution_hw || []).join("x")} px, ${plural(optics.frames, "frame")}, `
    + `${plural((optics.wavelengths_nm || []).length, "color")}, preset ${o.preset}, encoder ${o.encoder}`
    + (o.render_time_limit_s ? `, rendered for ${fmtSeconds(o.render_time_limit_s)}` : "")
    + (o.spp ? `, ${o.render_time_limit_s ? "at most " : ""}${plural(o.spp, "ray")} per pixel` : ""));
  fact(dl, "Time", `estimated ${fmtSeconds(est.seconds)} (${est.model || "–"}), actual `
    + `${actual === null ? "–" : fmtSeconds(actual)}${t.reused ? " (reused an earlier result)" : ""}`);
  fact(dl, "Memory", `estimated peak ${fmtBytes((est.memory || {}).peak_bytes)} (${(est.memory || {}).peak_stage || "–"}), `
    + `measured peak ${fmtBytes(t.peak_rss_bytes)}`);
  if (typeof t.engine === "string") fact(dl, "Ran on", `the ${t.engine} engine${job.attempts > 1 ? `, attempt ${job.attempts}` : ""}`);
  fact(dl, "Created", fmtTime(job.created_at));
  if (job.finished_at) fact(dl, "Finished", fmtTime(job.finished_at));
  if (job.reused_from) fact(dl, "Reused from", el("a", { href: `#/jobs/${job.reused_from}` }, job.reused_from));
  const p = pct(job);
  $("job-bar").style.width = `${(100 * p).toFixed(1)}%`;
  $("job-bar").dataset.fraction = String(p);
  const left = eta(job);
  setText($("job-stage"), FINAL.has(job.state) ? "" : `${Math.round(100 * p)}% · ${job.progress ? job.progress.step + " / "
    + job.progress.stage : "waiting for a worker"}${left && job.state === "running" ? " · " + left : ""}`
    + (job.state === "queued" && left ? ` (${left})` : ""));
  setText($("job-error"), job.error ? `Failed: ${job.error}` : "");
  renderActions(job);

  const plan = clear($("plan"));
  const own = ownPlan(job);
  for (const line of (own && own.summary) || []) plan.append(el("li", {}, line));
  if (!plan.firstChild) {
    plan.append(el("li", { class: "muted", id: "plan-note" }, FINAL.has(job.state)
      ? (job.state === "succeeded" ? "The render recorded no plan." : `No effect plan: the job ${job.state === "failed" ? "failed" : "was cancelled"} before its render made one.`)
      : "The effect plan at this job's options comes when it renders."));
  }
  const warns = clear($("warnings"));
  for (const w of (own && own.warnings) || (job.plan && job.plan.warnings) || []) warns.append(el("li", {}, w));

  const tb = clear($("timings").tBodies[0]);
  for (const [k, v] of Object.entries(t)) {
    if (k === "peak_rss_bytes" || typeof v !== "number" || !k.endsWith("_s")) continue;
    tb.append(el("tr", {}, el("td", {}, k.replace(/_s$/, "")), el("td", { class: "num" }, v.toFixed(2))));
  }
  const none = !tb.firstChild;
  $("timings").hidden = none;
  setText($("timings-note"), !none ? "" : t.reused ? "Reused an earlier result: nothing ran."
    : job.state === "queued" ? "Nothing has run yet." : job.state === "running" ? "The steps' seconds come when it finishes."
    : `No step timings: the job ${job.state === "failed" ? "failed" : "was cancelled"} before it finished.`);
  renderDownloads(job);
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

// Re-run with changes: the form takes the job's scene, optics (as a "profile" of its own) and options.
async function prefillRerun(job) {
  forgetScene();
  const sc = await getJSON(`/v1/scenes/${encodeURIComponent(job.scene_id)}`);
  state.scenes.set(sc.id, sc);
  state.scene = sc;
  state.rerun = job;
  showScene(sc);
  const o = job.options || {};
  const optics = o.optics || {};
  const sel = $("profile");
  sel.prepend(el("option", { value: `job:${job.id}` }, `as job ${jobName(job)} (${(optics.resolution_hw || []).join("x")}, `
    + `${optics.pitch_um} µm, ${plural((optics.wavelengths_nm || []).length, "color")})`));
  sel.value = `job:${job.id}`;
  $("res-h").value = optics.resolution_hw[0];
  $("res-w").value = optics.resolution_hw[1];
  $("frames").value = optics.frames;
  $("preset").value = o.preset;
  $("encoder").value = o.encoder;
  $("time-limit").value = o.render_time_limit_s || "";
  $("spp").value = o.spp && !o.render_time_limit_s ? o.spp : "";
  $("iterations").value = o.iterations ?? "";
  $("wrp-planes").value = String(o.wrp_planes || "auto");
  $("display").value = job.display || "";
  $("job-name").value = `${jobName(job)} (re-run)`.slice(0, 120);
  setText($("rerun-note"), `Re-run of job ${jobName(job)} (${job.id}) on its scene: change what you want and submit.`);
  show("rerun-note", true);
  show("job-form", true);
  $("submit").scrollIntoView();
  if (sc.plan_state !== "ready" && sc.plan_state !== "failed") waitForPlan(sc.id);
  estimateSoon();
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
  let first = null;
  for (const entry of logs) {
    const b = el("button", { type: "button", class: "small", "data-step": entry.step }, `${entry.step}.log (${fmtBytes(entry.bytes)})`);
    b.addEventListener("click", () => open(entry, b));
    tabs.append(b);
    if (entry.step !== "driver") first = [entry, b];  // the last step that ran (the failing one on a failed job)
  }
  if (first) await open(...first);
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
  for (const id of ["job-id", "job-name-title", "job-stage", "job-error", "look-note", "timings-note", "log-text",
                    "focus-label", "grid-label"]) setText($(id), "");
  $("job-bar").style.width = "0"; $("job-bar").dataset.fraction = "0";
  $("sweep-img").removeAttribute("src"); $("preview-img").removeAttribute("src");
  for (const id of ["look", "logs-card", "job-cancel", "job-delete", "job-rerun"]) show(id, false);
}

async function showJob(id) {
  leaveJobPage();
  const page = { id, abort: new AbortController(), urls: [] };
  state.page = page;
  resetJobPage();
  let job;
  try {
    job = await getJSON(`/v1/jobs/${id}`, { signal: page.abort.signal });
  } catch (err) {
    if (aborted(err) || state.page !== page) return;
    setText($("job-id"), id);
    setText($("job-error"), err.status === 404 ? "No such job (or it is another owner's)." : err.message);
    show("timings-card", false);
    return;
  }
  show("timings-card", true);
  await sceneName(job.scene_id);
  if (state.page !== page) return;
  renderJob(job);
  if (!FINAL.has(job.state)) {
    try {
      await streamEvents(`/v1/jobs/${id}/events`, (name, data) => {
        if (name === "state") job = data;
        else if (name === "progress") job = { ...job, state: data.state, progress: data };
        renderJob(job);
      }, page.abort.signal);
    } catch (_) { if (page.abort.signal.aborted) return; }
    if (state.page !== page) return;
    job = await getJSON(`/v1/jobs/${id}`, { signal: page.abort.signal });
    if (state.page !== page) return;
    renderJob(job);
  }
  await showLogs(job, page);
  if (state.page !== page) return;
  if (job.state === "succeeded") await showPictures(job, page);
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

// ---- start ----------------------------------------------------------------------------------------------------
function init() {
  setUnauthorizedHandler(() => signedOut("Signed out: the token is no longer accepted."));
  $("signin-form").addEventListener("submit", signIn);
  $("signout").addEventListener("click", () => signedOut());
  $("refresh").addEventListener("click", refreshHome);
  $("upload-form").addEventListener("submit", upload);
  $("job-form").addEventListener("submit", submit);
  $("job-form").addEventListener("input", estimateSoon);
  // a select may say only "change"; a text box's change (on leaving it) follows an input event already, and
  // re-estimating then would turn Submit off under the click that left the box
  $("job-form").addEventListener("change", (ev) => { if (ev.target.tagName === "SELECT") estimateSoon(); });
  $("bundle").addEventListener("change", () => { forgetScene(); clear($("scene-info")); });
  $("profile").addEventListener("change", () => { applyProfile(); estimateSoon(); });
  window.addEventListener("hashchange", route);
  if (token.get()) start().catch(() => signedOut("Please sign in again.")); else signedOut();
}

init();
