// The home page's job list (live progress over event streams, thumbnails) and the displays table.

import { ApiError, blobURL, getJSON, streamEvents } from "./api.js";
import { $, clear, el, fmtBytes, fmtSeconds, fmtShortTime, fmtTime } from "./dom.js";
import { actualSeconds, eta, jobName, lowQualityFlag, optionsText, pct } from "./job_facts.js";
import { applyJobFilters, refreshQueue } from "./job_filters.js";
import { showJobsSelection } from "./jobs_batch.js";
import { tickBox } from "./selection.js";
import { FINAL, MAX_STREAMS, show, state, status } from "./state.js";

export async function sceneName(id) {
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

function estimateCells(job) {
  const est = job.estimate || {};
  const mem = est.memory || {};
  const t = job.timings || {};
  const actual = actualSeconds(job, job.live);
  const reused = t.reused ? " (reused)" : "";
  return [
    el("td", { class: "num" }, `${fmtSeconds(est.seconds)} / ${actual === null ? "–" : fmtSeconds(actual)}${reused}`),
    el("td", { class: "num" }, `${fmtBytes(mem.peak_bytes)} / ${fmtBytes(t.peak_rss_bytes)}`),
  ];
}

function progressCell(job) {
  const p = pct(job);
  const stage = job.progress && job.progress.stage ? job.progress.stage : "";
  const left = eta(job, job.live);
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
    el("td", { class: "pick" }, tickBox(job.id, state.ticked)),
    thumbCell(job),
    el("td", { class: "job-name" }, el("a", { href: `#/jobs/${job.id}` }, jobName(job)),
       el("div", { class: "mono muted" }, job.id)),
    el("td", { class: "state" }, el("span", { class: `badge ${job.state}` }, job.state),
       job.error ? el("div", { class: "error reason" }, job.error) : null,
       lowQualityFlag(job) ? el("div", { class: "quality-flag" }, lowQualityFlag(job)) : null),
    progressCell(job),
    el("td", { class: "scene-name", title: job.scene_id }, scene),
    el("td", { class: "options" }, optionsText(job)),
    el("td", {}, job.display || "–"),
    ...estimateCells(job),
    el("td", { class: "num", title: fmtTime(job.created_at) }, fmtShortTime(job.created_at)));
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
  showJobsSelection();  // a ticked job that finished may now be deleted, no longer cancelled
}

export async function refreshHome() {
  try {
    const { jobs } = await getJSON("/v1/jobs?limit=100");
    await Promise.all([...new Set(jobs.map((j) => j.scene_id))].map(sceneName));
    const body = clear($("jobs").tBodies[0]);
    for (const j of jobs) { state.jobs.set(j.id, j); body.append(jobRow(j)); }
    show("jobs-empty", jobs.length === 0);
    applyJobFilters();
    showJobsSelection();
    refreshQueue();
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
    // the live view's time left (its steps' estimates at the measured pace) is kept with the job for its row
    if (name === "state") updateRow({ ...data, live: job.live });
    else if (name === "progress") updateRow({ ...job, state: data.state, progress: data });
    else if (name === "live") {
      updateRow({ ...job, live: { id, state: data.state, left_s: data.left_s, elapsed_s: data.elapsed_s } });
    }
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
    const showing = d.showing ? `${d.showing.job_id} frame ${d.showing.frame + 1}` : "–";  // from 1, as on the job page
    body.append(el("tr", {},
      el("td", {}, d.name), el("td", {}, d.owner || "–"), el("td", {}, d.state || "–"),
      el("td", { class: "mono" }, showing), el("td", { class: "message" }, d.message || ""),
      el("td", {}, `${fmtSeconds(d.age_s)} ago`)));
  }
  show("displays-empty", displays.length === 0);
}
