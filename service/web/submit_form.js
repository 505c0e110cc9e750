// The submit form: upload a bundle, the options (a display profile's, or a job's to re-run it with changes),
// the estimate and the effect plan at the chosen options, and Submit, which only sends what the estimate
// just accepted on a scene whose plan is ready.

import { ApiError, getJSON, postJSON, request } from "./api.js";
import { $, clear, el, fmtBytes, fmtSeconds, setText } from "./dom.js";
import { loadText } from "./job_facts.js";
import { plural, show, state } from "./state.js";
import { clearFormPicture, refuseFormBox, showFormPicture } from "./scene_picture.js";
import { refreshQueue } from "./job_filters.js";
import { showSweepChoice, sweepChoice } from "./sweep.js";

// The boxes the service's option limits bound (GET /v1/job-options: the options model's limits tightened by the
// service's), so that a box turns red exactly where the service would refuse: option -> the boxes' ids.
const LIMITED_BOXES = { frames: ["frames"], iterations: ["iterations"], spp: ["spp"], quality_db: ["quality-db"],
                        render_time_limit_s: ["time-limit"], resolution_px: ["res-h", "res-w"] };

function applyLimits(limits) {
  for (const [name, ids] of Object.entries(LIMITED_BOXES)) {
    const { min, max } = limits[name];
    for (const id of ids) {
      if (min !== null && name !== "render_time_limit_s") $(id).min = min;  // a time limit only above 0
      if (max !== null) $(id).max = max;
    }
  }
  const planes = $("wrp-planes");
  planes.replaceChildren(planes.options[0]);  // "auto", then every count the service takes
  for (let n = limits.wrp_planes.min; n <= limits.wrp_planes.max; n++) planes.append(el("option", { value: n }, String(n)));
}

function framesMost() { return state.optionLimits ? state.optionLimits.frames.max : Infinity; }

export async function loadProfiles() {
  state.optionLimits = (await getJSON("/v1/job-options")).options;
  applyLimits(state.optionLimits);
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

// The options of a size of the profile: a first job is a preview (half the display's rows and columns, a few
// frames, the fast preset: minutes, not hours); the full display is one choice away, its time shown beside.
const PREVIEW = { scale: 0.5, frames: 4, preset: "fast" };

function sizeOptions(size) {
  const o = profile().optics;
  if (size !== "preview") {
    return { res: o.resolution_hw, frames: Math.min(o.frames, framesMost()), preset: "balanced" };
  }
  return { res: o.resolution_hw.map((n) => Math.max(8, Math.round(n * PREVIEW.scale))),
           frames: Math.min(PREVIEW.frames, o.frames, framesMost()), preset: PREVIEW.preset };
}

function applyProfile() {
  const isJob = $("profile").value.startsWith("job:");
  const s = sizeOptions(isJob ? "full" : $("size").value);
  $("res-h").value = s.res[0];
  $("res-w").value = s.res[1];
  $("frames").value = s.frames;
  if (!isJob) $("preset").value = s.preset;
}

function jobBody() {
  const o = { ...profile().optics };
  delete o.frames;
  o.resolution_hw = [Number($("res-h").value), Number($("res-w").value)];
  if ($("scene-scale").value) o.scene_scale = Number($("scene-scale").value);  // else the profile's (1: as modelled)
  const body = { scene_id: state.scene.id, optics: o, preset: $("preset").value, frames: Number($("frames").value),
                 encoder: $("encoder").value };
  if ($("spp").value) body.spp = Number($("spp").value);
  if (body.encoder === "sgd") body.optimiser = $("optimiser").value;
  if ($("iterations").value && body.encoder === "sgd") body.iterations = Number($("iterations").value);
  if ($("time-limit").value) body.render_time_limit_s = Number($("time-limit").value);
  body.method = $("method").value;
  const planes = $("wrp-planes").value;
  body.wrp_planes = planes === "auto" ? "auto" : Number(planes);
  if ($("display").value.trim()) body.display = $("display").value.trim();
  if ($("job-name").value.trim()) body.name = $("job-name").value.trim();
  body.evaluate = $("evaluate").checked;
  if ($("quality-db").value) {  // the service chooses rays, iterations and frames (up to Frames) for the target
    body.quality_db = Number($("quality-db").value);
    for (const k of ["spp", "iterations", "render_time_limit_s"]) delete body[k];
  }
  return body;
}

// The form's state goes with the scene it was made for: a new upload (refused or not) takes the old one away
// first, so Submit can never send the previous scene.
export function forgetScene() {
  state.scene = null;
  state.rerun = null;
  estimateSeq++; clearTimeout(estimateTimer);
  show("job-form", false); show("rerun-note", false); show("form-plan-box", false);
  $("submit-button").disabled = true;
  setText($("estimate"), ""); setText($("quality"), ""); setText($("submit-error"), "");
  $("scene-scale").value = "";  // a scale is one scene's: the next scene's plan suggests its own
  const sel = $("profile");
  for (const o of [...sel.options]) if (o.value.startsWith("job:")) o.remove();
  if (!sel.value && state.profiles) { sel.value = state.profiles.default; applyProfile(); }
  clearFormPicture();
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

export function showScene(sc) {
  const r = sc.report || {};
  const info = clear($("scene-info"));
  info.append(
    el("p", {}, "Scene ", el("strong", { id: "scene-entry" }, sc.entry), " ",
       el("span", { class: "mono muted" }, sc.id)),
    el("p", { class: "muted" }, `${(r.files || []).length} files, ${fmtBytes(r.total_bytes)}; plugins: `
       + `${(r.plugins || []).join(", ") || "–"}; effect plan: ${sc.plan_state}`));
  for (const w of [...(r.warnings || []), ...(r.ignored || [])]) info.append(el("p", { class: "warning" }, String(w)));
  if (sc.plan_error) info.append(el("p", { class: "error" }, sc.plan_error));
  const focus = (sc.plan || {}).focus;  // holocore.plan.focus_depth: a scale that brings the scene to an eye's focus
  const suggested = focus && focus.suggested_scene_scale;
  $("scene-scale").placeholder = suggested ? `1 (as modelled); suggested ${suggested}` : "1 (as modelled)";
  if (focus) info.append(el("p", { id: "scene-focus", class: suggested ? "warning" : "muted" }, focus.summary));
  showFormPicture(sc, null);
}

// Follows the form's scene until its plan is ready or has failed, however long the planner's queue is (a
// failed request is tried again); Submit waits for it.
export async function waitForPlan(id) {
  for (let i = 0; ; i++) {
    await new Promise((r) => setTimeout(r, i < 30 ? 1000 : 3000));
    if (!state.scene || state.scene.id !== id || !state.me) return;
    try {
      const sc = await getJSON(`/v1/scenes/${id}`);
      if (!state.scene || state.scene.id !== id) return;
      if (sc.plan_state !== state.scene.plan_state) {
        state.scene = sc; state.scenes.set(id, sc); showScene(sc); estimateSoon();
      }
      if (sc.plan_state === "ready" || sc.plan_state === "failed") {
        if ($("queue-line")) refreshQueue();  // the planner's line no longer counts this scene
        return;
      }
    } catch (err) { if (err instanceof ApiError && (err.status === 401 || err.status === 404)) return; }
  }
}

// A job may only be submitted on a scene Mitsuba has loaded: until its plan is ready the scene may still fail
// (a job on it would fail with it), so Submit waits for the plan.
const planReady = () => !!state.scene && state.scene.plan_state === "ready";

let estimateTimer = null;
let estimateSeq = 0;
export function estimateSoon() {
  $("submit-button").disabled = true;
  clearTimeout(estimateTimer);
  estimateTimer = setTimeout(estimate, 250);
}

// Boxes that must hold something (their label's words); every other check is the server's, whose refusal says
// what to change (the browser's own range checks would only say "invalid").
const REQUIRED = [["frames", "Frames"], ["res-h", "Resolution (rows)"], ["res-w", "Resolution (columns)"]];
// A box the browser shows red (out of its own range) is refused here too, in its label's words: the page never
// estimates or submits what it marks as wrong.
const RANGED = [...REQUIRED, ["spp", "Rays per pixel"], ["iterations", "Encoder iterations"],
                ["time-limit", "Render time limit"], ["quality-db", "Quality target"], ["display", "Display name"]];

function outOfRange() {
  for (const [id, words] of RANGED) {
    const box = $(id);
    const v = box.validity;
    if (!v || v.valid) continue;
    if (v.patternMismatch) return `${words}: letters, digits, '.', '_' or '-', starting with a letter or digit.`;
    if (v.badInput) return `${words} must be a number.`;
    if (box.min && box.max) return `${words} must be ${box.min} to ${box.max}.`;
    return box.min ? `${words} must be at least ${box.min}.` : `${words} must be at most ${box.max}.`;
  }
  return null;
}

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
  if (empty.length) {
    setText(out, `Fill in ${empty.join(", ")} to see the estimate.`); showFormPlan(null); refuseFormBox();
    return;
  }
  const wrong = outOfRange();
  if (wrong) {
    setText(out, `Cannot submit: ${wrong}`);
    out.classList.add("error"); showFormPlan(null); refuseFormBox();
    return;
  }
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
    const ev = typeof e.estimate.evaluate_s === "number" ? `; the evaluation ${fmtSeconds(e.estimate.evaluate_s)} of that` : "";
    const loaded = loadText(e.estimate);
    setText(out, `Estimate: ${loaded || fmtSeconds(e.estimate.seconds)} (${e.estimate.model}; ${rays}${ev}), peak memory ${fmtBytes(m.peak_bytes)} in ${m.peak_stage || "–"} of ${fmtBytes(e.worker_memory_bytes)}`
      + (e.reuses ? `; the result of job ${e.reuses} would be reused at once` : ""));
    out.classList.remove("error");
    // the quality's own warnings go with the quality line, below the button (it must not move as it is clicked)
    const qw = new Set(((e.estimate.quality || {}).warnings) || []);
    for (const w of e.warnings || []) {
      if (!qw.has(w)) out.append(el("span", { class: "warning estimate-warning" }, ` · ${w}`));
    }
    showQuality(e.estimate.quality, e.options);
    if ($("size").value === "preview" && !$("profile").value.startsWith("job:")) fullEstimate(seq);
    showFormPlan(e.plan);
    showFormPicture(state.scene, e.field_of_view_box);
    if (!planReady()) out.append(el("span", { class: "muted", id: "plan-wait" },
      " · Submit waits for the scene's plan (Mitsuba loading the scene)…"));
    $("submit-button").disabled = !planReady();
  } catch (err) {
    if (seq !== estimateSeq) return;
    setText(out, `Cannot submit: ${err.message}`);
    out.classList.add("error");
    showFormPlan(null);
    refuseFormBox();
  }
}

// The full display's time beside a preview's estimate, and the choice of it one click away.
async function fullEstimate(seq) {
  const s = sizeOptions("full");
  const body = { ...jobBody(), frames: s.frames, preset: s.preset };
  body.optics = { ...body.optics, resolution_hw: s.res };
  let text;
  try {
    const e = await postJSON("/v1/jobs/estimate", body);
    text = `the full display (${s.res.join("x")}, ${plural(s.frames, "frame")}, ${s.preset}) would take `
      + `${loadText(e.estimate) || fmtSeconds(e.estimate.seconds)}`;
  } catch (err) {
    text = `the full display (${s.res.join("x")}): ${err.message}`;
  }
  if (seq !== estimateSeq || !state.scene) return;
  const span = el("span", { class: "muted", id: "full-estimate" }, ` · This is a preview; ${text} `);
  const go = el("button", { type: "button", class: "small", id: "full-size" }, "Use the full display");
  go.addEventListener("click", () => { $("size").value = "full"; applyProfile(); estimateSoon(); });
  span.append(go);
  $("estimate").append(span);
}

// What the options buy: the predicted viewer-faithful PSNR, what costs the most, the options a quality target
// chose, and other mixes worth knowing (service/quality.py).
function showQuality(q, chosen) {
  const out = clear($("quality"));
  if (!q) return;
  const parts = Object.entries(q.parts_db || {}).sort((a, b) => b[1] - a[1])
    .map(([k, v]) => `${k} ${v.toFixed(1)} dB`).join(", ");
  out.append(el("span", { id: "quality-predicted" },
    `Quality: expected about ${Math.round(q.psnr_db)} dB (±${q.uncertainty_db}) viewer-faithful PSNR; what each part costs: ${parts}`));
  if (chosen) {
    const it = chosen.iterations === null ? "the encoder's default run" : `${chosen.iterations} encoder iterations`;
    out.append(el("span", { id: "quality-chosen" },
      ` · for ${q.target_db} dB: ${chosen.frames} frames, ${chosen.spp === null ? "the preset's rays" : `${chosen.spp} rays per pixel`}, ${it}`));
  }
  for (const w of q.warnings || []) out.append(el("span", { class: "warning estimate-warning" }, ` · ${w}`));
  for (const line of q.instead || []) out.append(el("span", { class: "muted quality-instead" }, ` · instead: ${line}`));
}

async function submit(ev) {
  ev.preventDefault();
  if (!planReady() || $("submit-button").disabled) return;  // only what the estimate just accepted goes out
  $("submit-button").disabled = true;
  const sweep = sweepChoice();
  if (sweep) return submitSweep(sweep);
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

// The form's sweep (sweep.js): one job per value of one option, the sweep's page next.
async function submitSweep(sweep) {
  try {
    if (sweep.error) throw new Error(sweep.error);
    const s = await postJSON("/v1/sweeps", { job: jobBody(), option: sweep.option, values: sweep.values });
    location.hash = `#/sweeps/${s.id}`;
  } catch (err) {
    setText($("submit-error"), `Not submitted: ${err.message}`);
    $("submit-button").disabled = false;
  }
}

export function cancelEstimate() { clearTimeout(estimateTimer); estimateSeq++; }

// Signing out: the form as a fresh page has it, so the next person sees nothing of this one's scene or options.
export function resetForm() {
  cancelEstimate();
  forgetScene();
  state.rerunPending = null;
  clear($("scene-info"));
  $("upload-form").reset();
  $("job-form").reset();
  showSweepChoice();
  if (state.profiles) { $("profile").value = state.profiles.default; applyProfile(); }
}

// The form's own listeners (the page's start calls this once).
export function initForm() {
  $("upload-form").addEventListener("submit", upload);
  $("job-form").addEventListener("submit", submit);
  $("job-form").addEventListener("input", estimateSoon);
  // a select may say only "change"; a text box's change (on leaving it) follows an input event already, and
  // re-estimating then would turn Submit off under the click that left the box
  $("job-form").addEventListener("change", (ev) => { if (ev.target.tagName === "SELECT") estimateSoon(); });
  $("bundle").addEventListener("change", () => { forgetScene(); clear($("scene-info")); });
  $("profile").addEventListener("change", () => { applyProfile(); estimateSoon(); });
  $("size").addEventListener("change", () => { applyProfile(); estimateSoon(); });
}
