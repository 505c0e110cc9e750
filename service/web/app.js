// The results page: sign in with a token, the job list with live progress, a submit form with the estimate,
// and a job page with the plan, timings, downloads and what the hologram looks like (focal sweep, view grid).
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
  timer: null,
};

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
    showJob(m[1]);
  } else {
    show("job", false); show("home", true);
    refreshHome();
    state.timer = setInterval(refreshHome, 10000);
    if (state.scene) estimateSoon();
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

function pct(job) {
  const f = job.progress && typeof job.progress.fraction === "number" ? job.progress.fraction : 0;
  return job.state === "succeeded" ? 1 : Math.max(0, Math.min(1, f));
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
  return el("td", {},
    el("progress", { max: "1", value: String(p) }),
    el("span", { class: "muted" }, ` ${Math.round(100 * p)}%${stage && !FINAL.has(job.state) ? " " + stage : ""}`));
}

function jobRow(job) {
  const scene = state.scenes.has(job.scene_id) ? state.scenes.get(job.scene_id).entry : job.scene_id;
  return el("tr", { "data-job-id": job.id, class: `state-${job.state}` },
    el("td", {}, el("a", { href: `#/jobs/${job.id}`, class: "mono" }, job.id)),
    el("td", { class: "scene-name", title: job.scene_id }, scene),
    el("td", {}, job.display || "–"),
    el("td", {}, el("span", { class: `badge ${job.state}` }, job.state)),
    progressCell(job),
    ...estimateCells(job),
    el("td", {}, fmtTime(job.created_at)));
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
    await refreshDisplays();
    status("");
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
  return state.profiles.profiles.find((p) => p.name === $("profile").value) || state.profiles.profiles[0];
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
  if ($("time-limit").value) body.render_time_limit_s = Number($("time-limit").value);
  const planes = $("wrp-planes").value;
  body.wrp_planes = planes === "auto" ? "auto" : Number(planes);
  if ($("display").value.trim()) body.display = $("display").value.trim();
  return body;
}

async function upload(ev) {
  ev.preventDefault();
  const file = $("bundle").files[0];
  if (!file) return;
  const fd = new FormData();
  fd.append("bundle", file, "bundle.zip");
  if ($("entry").value.trim()) fd.append("entry", $("entry").value.trim());
  $("upload-button").disabled = true;
  const info = clear($("scene-info"));
  info.append(el("p", { class: "muted" }, "Uploading and checking the bundle…"));
  try {
    const sc = await (await request("/v1/scenes", { method: "POST", body: fd })).json();
    state.scene = sc;
    state.scenes.set(sc.id, sc);
    showScene(sc);
    show("job-form", true);
    estimateSoon();
    waitForPlan(sc.id);
  } catch (err) {
    clear(info).append(el("p", { class: "error" }, `Scene refused: ${err.message}`));
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
  if (sc.plan && sc.plan.summary) info.append(el("ul", { class: "plan" }, sc.plan.summary.map((s) => el("li", {}, s))));
  for (const w of [...(r.warnings || []), ...(r.ignored || [])]) info.append(el("p", { class: "warning" }, String(w)));
  if (sc.plan_error) info.append(el("p", { class: "error" }, sc.plan_error));
}

async function waitForPlan(id) {
  for (let i = 0; i < 120; i++) {
    await new Promise((r) => setTimeout(r, 1000));
    if (!state.scene || state.scene.id !== id) return;
    try {
      const sc = await getJSON(`/v1/scenes/${id}`);
      if (sc.plan_state !== state.scene.plan_state) {
        state.scene = sc; state.scenes.set(id, sc); showScene(sc); estimateSoon();
      }
      if (sc.plan_state === "ready" || sc.plan_state === "failed") return;
    } catch (_) { return; }
  }
}

let estimateTimer = null;
let estimateSeq = 0;
function estimateSoon() {
  $("submit-button").disabled = true;
  clearTimeout(estimateTimer);
  estimateTimer = setTimeout(estimate, 250);
}

async function estimate() {
  if (!state.scene) return;
  const seq = ++estimateSeq;
  const out = $("estimate");
  setText($("submit-error"), "");
  if (!$("job-form").checkValidity()) { setText(out, "Fill in the options to see the estimate."); return; }
  try {
    const e = await postJSON("/v1/jobs/estimate", jobBody());
    if (seq !== estimateSeq) return;
    const m = e.estimate.memory || {};
    const rays = e.estimate.spp_assumed === null ? "rays until the time limit"
      : `${e.estimate.spp_assumed} rays per pixel`;
    setText(out, `Estimate: ${fmtSeconds(e.estimate.seconds)} (${e.estimate.model}; ${rays}), peak memory ${fmtBytes(m.peak_bytes)} in ${m.peak_stage || "–"} of ${fmtBytes(e.worker_memory_bytes)}`
      + (e.reuses ? `; the result of job ${e.reuses} would be reused at once` : ""));
    out.classList.remove("error");
    $("submit-button").disabled = false;
  } catch (err) {
    if (seq !== estimateSeq) return;
    setText(out, `Cannot submit: ${err.message}`);
    out.classList.add("error");
  }
}

async function submit(ev) {
  ev.preventDefault();
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

function renderJob(job) {
  setText($("job-id"), job.id);
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
  fact(dl, "Options", `${(optics.resolution_hw || []).join("x")} px, ${optics.frames} frames, `
    + `${(optics.wavelengths_nm || []).length} colors, preset ${o.preset}, encoder ${o.encoder}`
    + (o.render_time_limit_s ? `, rendered for ${fmtSeconds(o.render_time_limit_s)}` : "")
    + (o.spp ? `, ${o.render_time_limit_s ? "at most " : ""}${o.spp} rays per pixel` : ""));
  fact(dl, "Time", `estimated ${fmtSeconds(est.seconds)} (${est.model || "–"}), actual `
    + `${actual === null ? "–" : fmtSeconds(actual)}${t.reused ? " (reused an earlier result)" : ""}`);
  fact(dl, "Memory", `estimated peak ${fmtBytes((est.memory || {}).peak_bytes)} (${(est.memory || {}).peak_stage || "–"}), `
    + `measured peak ${fmtBytes(t.peak_rss_bytes)}`);
  fact(dl, "Created", fmtTime(job.created_at));
  if (job.finished_at) fact(dl, "Finished", fmtTime(job.finished_at));
  if (job.reused_from) fact(dl, "Reused from", el("a", { href: `#/jobs/${job.reused_from}` }, job.reused_from));
  const p = pct(job);
  $("job-bar").style.width = `${(100 * p).toFixed(1)}%`;
  setText($("job-stage"), FINAL.has(job.state) ? "" : `${Math.round(100 * p)}% · ${job.progress ? job.progress.step + " / "
    + job.progress.stage : "waiting for a worker"}`);
  setText($("job-error"), job.error || "");

  const plan = clear($("plan"));
  for (const line of (job.plan && job.plan.summary) || []) plan.append(el("li", {}, line));
  if (!plan.firstChild) plan.append(el("li", { class: "muted" }, job.plan && job.plan.source === "pending"
    ? "The effect plan follows once the scene has been planned." : "No plan yet."));
  const warns = clear($("warnings"));
  for (const w of (job.plan && job.plan.warnings) || []) warns.append(el("li", {}, w));

  const tb = clear($("timings").tBodies[0]);
  for (const [k, v] of Object.entries(t)) {
    if (k === "peak_rss_bytes") continue;
    tb.append(el("tr", {}, el("td", {}, k.replace(/_s$/, "")),
      el("td", { class: "num" }, typeof v === "number" ? v.toFixed(2) : String(v))));
  }
  renderDownloads(job);
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

async function showJob(id) {
  leaveJobPage();
  const page = { id, abort: new AbortController(), urls: [] };
  state.page = page;
  clear($("grid")); $("sweep-img").removeAttribute("src"); $("preview-img").removeAttribute("src");
  setText($("look-note"), "");
  show("look", false);
  let job;
  try {
    job = await getJSON(`/v1/jobs/${id}`);
  } catch (err) {
    setText($("job-id"), id);
    setText($("job-error"), err.status === 404 ? "No such job (or it is another owner's)." : err.message);
    return;
  }
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
    job = await getJSON(`/v1/jobs/${id}`);
    renderJob(job);
  }
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
  setText($("look-note"), `Simulated reconstruction (${idx.shape_hw.join("x")} px, ${idx.frames} frames averaged): `
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
  $("profile").addEventListener("change", () => { applyProfile(); estimateSoon(); });
  window.addEventListener("hashchange", route);
  if (token.get()) start().catch(() => signedOut("Please sign in again.")); else signedOut();
}

init();
