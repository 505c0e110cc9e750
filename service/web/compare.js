// Two to four jobs side by side (#/compare/A/B, up to #/compare/A/B/C/D): their focal sweeps under one focus
// slider, their previews, and the options in which they differ (one column per job). The slider runs over every
// sweep's focus depths together (far to near); each job shows its own picture nearest that depth, so jobs whose
// sweeps differ (another scene, another image volume) still compare at the same focus.

import { blobURL, getJSON } from "./api.js";
import { $, clear, el, fmtBytes, fmtSeconds, setText } from "./dom.js";
import { actualSeconds, jobName } from "./job_facts.js";
import { sceneName } from "./jobs_list.js";
import { COMPARE_MOST, compareHash } from "./selection.js";
import { aborted, state, status } from "./state.js";

const SIDES = ["a", "b", "c", "d"]; // the columns' id suffixes; COMPARE_MOST of them at most
const IDS = "[A-Za-z0-9_-]{1,64}";
// two sweeps' depths closer than this (mm), or than 1 % of the depths' span, are one slider position: a stop
// between them would change neither side's picture
const SAME_MM = 0.02;
const SAME_SPAN = 0.01;

let view = null; // {abort, urls, sides: [{job, sweep, urls}]}

export function leaveCompare() {
  if (!view) return;
  view.abort.abort();
  for (const u of view.urls) URL.revokeObjectURL(u);
  view = null;
}

// Every option as "name" -> text, the optics' fields under "optics." (a job's options are its stored spec). The
// request's "frames" is not listed beside them: the frames a job made are its optics' (optics.frames).
function flatOptions(job) {
  const out = new Map();
  const put = (key, v) => {
    if (v === null || v === undefined) return;
    out.set(key, Array.isArray(v) ? v.join(" x ") : typeof v === "object" ? JSON.stringify(v) : String(v));
  };
  const o = job.options || {};
  for (const [k, v] of Object.entries(o)) if (k !== "optics" && k !== "name" && k !== "frames") put(k, v);
  for (const [k, v] of Object.entries(o.optics || {})) put(`optics.${k}`, v);
  const sc = state.scenes.get(job.scene_id);
  put("scene", sc ? `${sc.entry} (${job.scene_id})` : job.scene_id);
  put("display", job.display);
  return out;
}

// The rows [option, value per job] in which the jobs differ (an option only some of them have counts as
// differing), and how many options they all share.
export function optionDiff(...jobs) {
  const flat = jobs.map(flatOptions);
  const keys = [...new Set(flat.flatMap((f) => [...f.keys()]))].sort();
  const rows = keys.filter((k) => new Set(flat.map((f) => f.get(k))).size > 1)
    .map((k) => [k, ...flat.map((f) => f.get(k) ?? "–")]);
  return { rows, same: keys.length - rows.length };
}

// The slider's positions: every sweep's depths (mm from the SLM) in the sweeps' own order (far to near, which
// is falling or rising z as the display maps the scene), one position for depths closer than SAME_MM or
// SAME_SPAN of the span.
export function sliderDepths(sweeps) {
  const first = sweeps.find((s) => s.length > 1);
  const falling = !first || first[0].z_mm > first[first.length - 1].z_mm;
  const all = sweeps.flatMap((s) => s.map((p) => p.z_mm)).sort((x, y) => (falling ? y - x : x - y));
  const span = all.length ? Math.abs(all[all.length - 1] - all[0]) : 0;
  const same = Math.max(SAME_MM, SAME_SPAN * span);
  const out = [];
  for (const z of all) if (!out.length || Math.abs(out[out.length - 1] - z) >= same) out.push(z);
  return out;
}

function nearest(pictures, z) {
  let best = 0;
  pictures.forEach((p, i) => { if (Math.abs(p.z_mm - z) < Math.abs(pictures[best].z_mm - z)) best = i; });
  return best;
}

async function loadSide(id, signal) {
  const job = await getJSON(`/v1/jobs/${encodeURIComponent(id)}`, { signal });
  await sceneName(job.scene_id);
  if (job.state !== "succeeded") return { job, sweep: [], urls: [], preview: null };
  const idx = await getJSON(`/v1/jobs/${encodeURIComponent(id)}/pictures`, { signal });
  const sweep = idx.sweep.pictures;
  const urls = await Promise.all(sweep.map((p) => blobURL(p.url, { signal })));
  let preview = null;
  try { preview = await blobURL(job.links.preview, { signal }); } catch (err) { if (aborted(err)) throw err; }
  return { job, sweep, urls, preview, pupil_mm: idx.sweep.pupil_mm };
}

function sideFacts(side) {
  const { job } = side;
  const t = job.timings || {};
  const o = job.options || {};
  const optics = o.optics || {};
  return `${(optics.resolution_hw || []).join("x")} px, ${optics.frames} frame(s), ${o.preset}, ${o.encoder}; `
    + `ran ${fmtSeconds(actualSeconds(job))}, peak ${fmtBytes(t.peak_rss_bytes)}`;
}

function renderSides(sides) {
  const depths = sliderDepths(sides.map((s) => s.sweep));
  const slider = $("cmp-focus");
  slider.max = String(Math.max(0, depths.length - 1));
  slider.value = String(Math.floor((depths.length - 1) / 2));
  const showFocus = () => {
    const z = depths[Number(slider.value)];
    const who = sides.length === 2 ? "both" : `all ${sides.length}`;
    setText($("cmp-focus-label"), z === undefined ? "" : `${who} focused at ${z.toFixed(3)} mm from the SLM`);
    sides.forEach((side, k) => {
      const s = SIDES[k];
      if (!side.sweep.length) return;
      const i = nearest(side.sweep, z);
      $(`cmp-img-${s}`).src = side.urls[i];
      $(`cmp-img-${s}`).dataset.index = String(i);
      setText($(`cmp-z-${s}`), `${side.sweep[i].z_mm.toFixed(3)} mm (${side.sweep[i].words})`);
    });
  };
  slider.oninput = showFocus;
  slider.disabled = depths.length < 2;
  showFocus();
}

function renderDiff(jobs) {
  const { rows, same } = optionDiff(...jobs);
  const head = clear($("cmp-diff").tHead.rows[0]);
  head.append(el("th", {}, "Option"),
              ...jobs.map((j, k) => el("th", { title: j.id }, `${label(jobs.length, k)}: ${jobName(j)}`)));
  const body = clear($("cmp-diff").tBodies[0]);
  for (const [k, ...values] of rows) {
    body.append(el("tr", { "data-option": k }, el("td", { class: "mono" }, k),
                   ...values.map((v) => el("td", {}, v))));
  }
  $("cmp-diff").hidden = rows.length === 0;
  const all = jobs.length === 2 ? "The two jobs" : `The ${jobs.length} jobs`;
  setText($("cmp-same"), rows.length ? `${same} other options are the same.` : `${all} have the same options (${same}).`);
}

const label = (n, k) => (n === 2 ? ["Left", "Right"][k] : `Job ${k + 1}`);

// One column per job, each with its picker, name, facts, view at the slider's focus and preview.
function buildSides(n) {
  const box = clear($("cmp-sides"));
  for (let k = 0; k < n; k++) {
    const s = SIDES[k], words = label(n, k).toLowerCase();
    box.append(el("div", { class: "compare-side", id: `cmp-side-${s}` },
      el("label", {}, label(n, k), " ", el("select", { id: `cmp-pick-${s}` })),
      el("h3", { id: `cmp-name-${s}` }), el("p", { id: `cmp-facts-${s}`, class: "muted" }),
      el("p", { id: `cmp-error-${s}`, class: "error" }),
      el("img", { id: `cmp-img-${s}`, class: "cmp-img", alt: `${words} job's view at the chosen focus` }),
      el("p", { id: `cmp-z-${s}`, class: "muted" }),
      n > 2 ? el("button", { type: "button", class: "small secondary", id: `cmp-drop-${s}` }, "Leave out") : null,
      el("img", { id: `cmp-preview-${s}`, class: "cmp-img", alt: `${words} job's preview` })));
  }
  box.dataset.count = String(n);
}

function fillPickers(ids) {
  const jobs = [...state.jobs.values()].filter((j) => j.state === "succeeded");
  for (const id of ids) if (!jobs.some((j) => j.id === id) && state.jobs.has(id)) jobs.push(state.jobs.get(id));
  const options = (sel) => {
    for (const j of jobs) sel.append(el("option", { value: j.id }, `${jobName(j)} (${j.id})`));
  };
  ids.forEach((id, k) => {
    const s = SIDES[k];
    const sel = clear($(`cmp-pick-${s}`));
    options(sel);
    if (!jobs.some((j) => j.id === id)) sel.append(el("option", { value: id }, id));
    sel.value = id;
    sel.onchange = () => { location.hash = compareHash(ids.map((x, i) => (i === k ? sel.value : x))); };
    const drop = $(`cmp-drop-${s}`);
    if (drop) drop.onclick = () => { location.hash = compareHash(ids.filter((_, i) => i !== k)); };
  });
  const add = clear($("cmp-add"));
  add.append(el("option", { value: "" }, "choose a job"));
  options(add);
  add.onchange = () => { if (add.value) location.hash = compareHash([...ids, add.value]); };
  $("cmp-more").hidden = ids.length >= COMPARE_MOST || !jobs.length;
}

// The compare page for 2 to 4 jobs; without ids, the two newest succeeded jobs.
export async function showCompare(ids) {
  leaveCompare();
  const here = { abort: new AbortController(), urls: [] };
  view = here;
  buildSides(ids ? ids.length : 2);
  clear($("cmp-diff").tBodies[0]); $("cmp-more").hidden = true;
  setText($("cmp-same"), ""); setText($("cmp-focus-label"), "");
  if (!ids) {
    const { jobs } = await getJSON("/v1/jobs?state=succeeded&limit=100", { signal: here.abort.signal });
    for (const j of jobs) state.jobs.set(j.id, j);
    if (jobs.length < 2) { setText($("cmp-same"), "Two succeeded jobs are needed to compare."); return; }
    location.replace(`#/compare/${jobs[1].id}/${jobs[0].id}`);  // older left, newer right
    return;
  }
  const sides = await Promise.all(ids.map((id, k) => loadSide(id, here.abort.signal).catch((err) => {
    if (aborted(err)) throw err;
    setText($(`cmp-error-${SIDES[k]}`), err.status === 404 ? `No such job ${id} (or it is another owner's).` : err.message);
    return null;
  })));
  if (view !== here) { for (const s of sides) if (s) [...s.urls, s.preview].forEach((u) => u && URL.revokeObjectURL(u)); return; }
  for (const s of sides) if (s) here.urls.push(...s.urls, ...(s.preview ? [s.preview] : []));
  fillPickers(ids);
  sides.forEach((side, k) => {
    const s = SIDES[k];
    if (!side) return;
    const name = $(`cmp-name-${s}`);
    clear(name).append(el("a", { href: `#/jobs/${side.job.id}` }, jobName(side.job)));
    setText($(`cmp-facts-${s}`), sideFacts(side));
    if (side.job.state !== "succeeded") setText($(`cmp-error-${s}`), `This job has ${side.job.state === "failed"
      ? "failed" : side.job.state === "cancelled" ? "been cancelled" : "not finished"}: nothing to show.`);
    if (side.preview) $(`cmp-preview-${s}`).src = side.preview;
  });
  const live = sides.filter(Boolean);
  if (live.length >= 2) renderDiff(live.map((side) => side.job));
  renderSides(sides.map((s) => s || { sweep: [], urls: [] }));
  setText($("cmp-pupil"), live.length ? `Simulated views with a ${live[0].pupil_mm || 4} mm pupil; each job at its own white level.` : "");
}

export function routeCompare(hash) {
  const m = new RegExp(`^#/compare((?:/${IDS}){2,${COMPARE_MOST}})?$`).exec(hash);
  if (!m) return false;
  showCompare(m[1] ? m[1].slice(1).split("/") : null).catch((err) => { if (!aborted(err)) status(`Could not compare: ${err.message}`, true); });
  return true;
}

// The job page's "Compare with": the owner's other succeeded jobs, newest first (the same scene's first).
export async function offerCompare(job, signal) {
  const box = $("job-compare");
  box.hidden = true;
  if (job.state !== "succeeded") return;
  const { jobs } = await getJSON("/v1/jobs?state=succeeded&limit=100", { signal });
  const others = jobs.filter((j) => j.id !== job.id);
  others.sort((x, y) => (y.scene_id === job.scene_id) - (x.scene_id === job.scene_id));
  if (!others.length) return;
  const sel = clear($("job-compare-pick"));
  for (const j of others) {
    state.jobs.set(j.id, j);
    sel.append(el("option", { value: j.id }, `${jobName(j)} (${j.id})${j.scene_id === job.scene_id ? "" : ", another scene"}`));
  }
  $("job-compare-go").onclick = () => { location.hash = `#/compare/${job.id}/${sel.value}`; };
  box.hidden = false;
}
