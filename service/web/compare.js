// Two jobs side by side (#/compare/A/B): their focal sweeps under one focus slider, their previews, and the
// options in which they differ. The slider runs over both sweeps' focus depths together (far to near); each
// side shows its own picture nearest that depth, so two jobs whose sweeps differ (another scene, another
// image volume) still compare at the same focus.

import { blobURL, getJSON } from "./api.js";
import { $, clear, el, fmtBytes, fmtSeconds, setText } from "./dom.js";
import { actualSeconds, jobName } from "./job_facts.js";
import { sceneName } from "./jobs_list.js";
import { aborted, state, status } from "./state.js";

const SIDES = ["a", "b"];
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

// The rows in which the two jobs differ (an option only one of them has counts as differing), and how many
// options they share.
export function optionDiff(a, b) {
  const fa = flatOptions(a), fb = flatOptions(b);
  const keys = [...new Set([...fa.keys(), ...fb.keys()])].sort();
  const rows = keys.filter((k) => fa.get(k) !== fb.get(k)).map((k) => [k, fa.get(k) ?? "–", fb.get(k) ?? "–"]);
  return { rows, same: keys.length - rows.length };
}

// The slider's positions: both sweeps' depths (mm from the SLM) in the sweeps' own order (far to near, which
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
    setText($("cmp-focus-label"), z === undefined ? "" : `both focused at ${z.toFixed(3)} mm from the SLM`);
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

function renderDiff(a, b) {
  const { rows, same } = optionDiff(a, b);
  const body = clear($("cmp-diff").tBodies[0]);
  for (const [k, va, vb] of rows) body.append(el("tr", { "data-option": k }, el("td", { class: "mono" }, k),
                                                 el("td", {}, va), el("td", {}, vb)));
  $("cmp-diff").hidden = rows.length === 0;
  setText($("cmp-same"), rows.length ? `${same} other options are the same.`
    : `The two jobs have the same options (${same}).`);
}

function fillPickers(ids) {
  const jobs = [...state.jobs.values()].filter((j) => j.state === "succeeded");
  for (const id of ids) if (!jobs.some((j) => j.id === id) && state.jobs.has(id)) jobs.push(state.jobs.get(id));
  SIDES.forEach((s, k) => {
    const sel = clear($(`cmp-pick-${s}`));
    for (const j of jobs) sel.append(el("option", { value: j.id }, `${jobName(j)} (${j.id})`));
    if (!jobs.some((j) => j.id === ids[k])) sel.append(el("option", { value: ids[k] }, ids[k]));
    sel.value = ids[k];
    sel.onchange = () => {
      const next = [...ids];
      next[k] = sel.value;
      location.hash = `#/compare/${next[0]}/${next[1]}`;
    };
  });
}

// The compare page for jobs a and b; without ids, the two newest succeeded jobs.
export async function showCompare(ids) {
  leaveCompare();
  const here = { abort: new AbortController(), urls: [] };
  view = here;
  for (const s of SIDES) {
    $(`cmp-img-${s}`).removeAttribute("src"); $(`cmp-preview-${s}`).removeAttribute("src");
    for (const id of ["name", "facts", "z", "error"]) setText($(`cmp-${id}-${s}`), "");
  }
  clear($("cmp-diff").tBodies[0]); setText($("cmp-same"), ""); setText($("cmp-focus-label"), "");
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
  if (live.length === 2) renderDiff(live[0].job, live[1].job);
  renderSides(sides.map((s) => s || { sweep: [], urls: [] }));
  setText($("cmp-pupil"), live.length ? `Simulated views with a ${live[0].pupil_mm || 4} mm pupil; each job at its own white level.` : "");
}

export function routeCompare(hash) {
  const m = /^#\/compare(?:\/([A-Za-z0-9_-]{1,64})\/([A-Za-z0-9_-]{1,64}))?$/.exec(hash);
  if (!m) return false;
  showCompare(m[1] ? [m[1], m[2]] : null).catch((err) => { if (!aborted(err)) status(`Could not compare: ${err.message}`, true); });
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
