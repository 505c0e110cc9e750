// Sweeps: the form's "Sweep" row (one option, several values: Submit then sends POST /v1/sweeps, one job per
// value) and a sweep's page (#/sweeps/ID): its jobs, live, with Cancel all, the chart of quality and time per
// value (sweep_chart.js), and actions on the jobs ticked in its list (selection.js: cancel, delete, compare).

import { getJSON, request } from "./api.js";
import { $, clear, el, fmtSeconds, setText } from "./dom.js";
import { pct } from "./job_facts.js";
import { actOnSelected, compareHash, selectionActions, showSelection, tickBox, tickedIds } from "./selection.js";
import { sweepChart } from "./sweep_chart.js";
import { FINAL, aborted, plural, state, status } from "./state.js";

const WORDS = new Set(["encoder", "optimiser", "preset", "method"]);  // the options whose values are words, not numbers

// The form's sweep: null without one, {error} when its values cannot be read, else {option, values}.
export function sweepChoice() {
  const option = $("sweep-option").value;
  if (!option) return null;
  const parts = $("sweep-values").value.split(",").map((s) => s.trim()).filter(Boolean);
  if (parts.length < 2 || parts.length > 12) return { error: `Sweep values: give 2 to 12 values of ${option}, `
    + "separated by commas (e.g. 1, 2, 4, 8)." };
  const values = [];
  for (const p of parts) {
    if (WORDS.has(option) || (option === "wrp_planes" && p === "auto")) { values.push(p); continue; }
    const n = Number(p);
    if (!isFinite(n)) return { error: `Sweep values: "${p}" is not a number (${option} takes numbers).` };
    values.push(n);
  }
  return { option, values };
}

// What Submit will do, beside the button.
export function showSweepChoice() {
  const s = sweepChoice();
  setText($("submit-button"), s && !s.error ? `Submit sweep (${plural(s.values.length, "job")})` : "Submit job");
  $("sweep-values").disabled = !$("sweep-option").value;
  setText($("sweep-note"), !s ? "" : s.error || `One job per value: ${s.option} = ${s.values.join(", ")}; `
    + "every other option as above.");
  $("sweep-note").classList.toggle("error", !!(s && s.error));
}

// The home page's line of the owner's latest sweeps, each a link to its page.
export async function refreshSweepsLine() {
  const line = $("sweeps-line");
  let sweeps = [];
  try { ({ sweeps } = await getJSON("/v1/sweeps?limit=5")); } catch (_) { /* the line stays as it was */ return; }
  clear(line);
  line.hidden = !sweeps.length;
  if (!sweeps.length) return;
  line.append("Sweeps: ");
  sweeps.forEach((s, i) => {
    const live = s.jobs.filter((j) => !FINAL.has(j.state)).length;
    line.append(i ? " · " : "", el("a", { href: `#/sweeps/${s.id}` }, `${s.option} = ${s.values.join(", ")}`),
                live ? ` (${live} to finish)` : "");
  });
}

// ---- a sweep's page ---------------------------------------------------------------------------------------------
let view = null; // {id, abort, timer, sweep}

export function leaveSweep() {
  if (!view) return;
  view.abort.abort();
  clearTimeout(view.timer);
  view = null;
}

export async function showSweep(id) {
  leaveSweep();
  view = { id, abort: new AbortController(), timer: null, sweep: null };
  clear($("sweep-jobs").tBodies[0]);
  clear($("sweep-chart"));
  setText($("sweep-title"), ""); setText($("sweep-note-page"), "");
  await refresh(view);
}

async function refresh(v) {
  let sweep;
  try {
    sweep = await getJSON(`/v1/sweeps/${encodeURIComponent(v.id)}`, { signal: v.abort.signal });
  } catch (err) {
    if (aborted(err) || view !== v) return;
    status(`Could not show the sweep: ${err.message}`, true);
    return;
  }
  if (view !== v) return;
  v.sweep = sweep;
  render(sweep);
  const live = sweep.jobs.some((j) => !FINAL.has(j.state));
  if (live) v.timer = setTimeout(() => refresh(v), 1500);
}

function render(sweep) {
  const done = sweep.jobs.filter((j) => FINAL.has(j.state)).length;
  setText($("sweep-title"), `${sweep.option} = ${sweep.values.join(", ")}`);
  setText($("sweep-summary"), `${plural(sweep.jobs.length, "job")}, ${done} finished`
    + (sweep.jobs.length < sweep.values.length ? ` (${sweep.values.length - sweep.jobs.length} deleted)` : ""));
  const evaluated = sweep.jobs.some((j) => typeof j.measured_psnr_db === "number");
  setText($("sweep-note-page"), evaluated ? "" : "Measured quality appears for jobs submitted with \"Evaluate "
    + "against ground truth\" once they have finished; the hollow points are the service's prediction.");
  $("sweep-cancel").disabled = !sweep.jobs.some((j) => !FINAL.has(j.state));
  const may = !!(state.me && state.me.may_submit);  // a read-only token watches; it cancels and deletes nothing
  for (const id of ["sweep-cancel", "sweep-cancel-selected", "sweep-delete-selected"]) $(id).hidden = !may;
  clear($("sweep-chart")).append(sweepChart(sweep));
  renderRows(sweep);
  selectionChanged();
}

function renderRows(sweep) {
  const body = $("sweep-jobs").tBodies[0];
  const ticked = new Set(tickedIds($("sweep-jobs")));
  clear(body);
  const db = (v) => (typeof v === "number" ? v.toFixed(1) : "–");
  for (const j of sweep.jobs) {
    const box = tickBox(j.id, ticked);
    const frac = pct(j);
    body.append(el("tr", { dataset: { id: j.id, state: j.state } },
      el("td", {}, box),
      el("td", { class: "num" }, String(j.value)),
      el("td", { class: "job-name" }, el("a", { href: `#/jobs/${j.id}` }, j.name || j.id)),
      el("td", {}, el("span", { class: `badge ${j.state}` }, j.state),
         j.error ? el("div", { class: "error" }, j.error) : null),
      el("td", {}, el("progress", { max: 1, value: frac }), ` ${Math.round(frac * 100)} %`),
      el("td", { class: "num" }, `${fmtSeconds(j.estimate_s)} / ${j.run_s === null ? "–" : fmtSeconds(j.run_s)}`),
      el("td", { class: "num" }, `${db(j.predicted_psnr_db)} / ${db(j.measured_psnr_db)}`)));
  }
}

const SELECTION = { cancel: "sweep-cancel-selected", remove: "sweep-delete-selected", compare: "sweep-compare",
                    count: "sweep-selected" };

// The ticked jobs' records, in the table's order.
function selectedJobs() {
  const rows = new Map(((view && view.sweep) || { jobs: [] }).jobs.map((j) => [j.id, j]));
  return tickedIds($("sweep-jobs")).map((id) => rows.get(id)).filter(Boolean);
}

function selectionChanged() { showSelection(selectedJobs(), SELECTION); }

async function act(which) {
  if ((await actOnSelected(which, selectedJobs(), $("sweep-delete-selected"))) === null) return;
  if (view) { clearTimeout(view.timer); await refresh(view); }
}

async function cancelAll() {
  if (!view) return;
  $("sweep-cancel").disabled = true;
  try {
    await request(`/v1/sweeps/${encodeURIComponent(view.id)}`, { method: "DELETE" });
    status("Cancelled the sweep's unfinished jobs.");
  } catch (err) { status(`Could not cancel: ${err.message}`, true); }
  if (view) { clearTimeout(view.timer); await refresh(view); }
}

export function initSweep() {
  $("sweep-option").addEventListener("change", showSweepChoice);
  $("sweep-values").addEventListener("input", showSweepChoice);
  $("sweep-cancel").addEventListener("click", cancelAll);
  $("sweep-jobs").addEventListener("change", selectionChanged);
  $("sweep-cancel-selected").addEventListener("click", () => act("cancel"));
  $("sweep-delete-selected").addEventListener("click", () => act("delete"));
  $("sweep-compare").addEventListener("click", () => {
    const jobs = selectedJobs();
    if (selectionActions(jobs).compare) location.hash = compareHash(jobs.map((j) => j.id));
  });
  showSweepChoice();
}
