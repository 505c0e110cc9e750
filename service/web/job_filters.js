// The job list's filters (state, a search over name, scene and id, display) and sort (created, name, state,
// run time), over the jobs the list loaded (the newest 100): rows are hidden and reordered in place, so the
// list's live updates (progress, thumbnails) keep working, and the choice survives the list's refresh every
// 10 s (and a visit to a job's page: it is kept in this tab's sessionStorage). Also the queue's line:
// jobs waiting, worker slots busy, the planner (GET /v1/queue), refreshed with the list.

import { getJSON } from "./api.js";
import { $, el, setText } from "./dom.js";
import { actualSeconds, jobName } from "./job_facts.js";
import { state } from "./state.js";

const KEY = "holo.jobFilters";
const STATES = ["queued", "running", "succeeded", "failed", "cancelled"];
const STATE_ORDER = { running: 0, queued: 1, failed: 2, succeeded: 3, cancelled: 4 }; // what needs a look first
const SORTS = [["created", "newest first"], ["name", "name"], ["state", "state"], ["runtime", "run time, longest first"]];
const NO_DISPLAY = "\u0000none"; // the display filter's "no display" (no display name can hold a NUL)

function saved() {
  try {
    const v = JSON.parse(sessionStorage.getItem(KEY) || "{}");
    return v && typeof v === "object" ? v : {};
  } catch (_) { return {}; }
}

const choice = { state: "", text: "", display: "", sort: "created", ...saved() };

function save() { sessionStorage.setItem(KEY, JSON.stringify(choice)); }

let observer = null;
let applying = false;

// The controls, built once above the table (the page's HTML only holds the table).
function controls() {
  let box = $("job-filters");
  if (box) return box;
  const stateSel = el("select", { id: "filter-state" }, el("option", { value: "" }, "all states"),
    ...STATES.map((s) => el("option", { value: s }, s)));
  const text = el("input", { id: "filter-text", type: "search", maxlength: "200", spellcheck: "false",
                             placeholder: "name, scene or id" });
  const display = el("select", { id: "filter-display" }, el("option", { value: "" }, "all displays"));
  const sort = el("select", { id: "sort-jobs" }, ...SORTS.map(([v, words]) => el("option", { value: v }, words)));
  box = el("div", { id: "job-filters", class: "job-filters" },
    el("label", {}, "State", stateSel), el("label", {}, "Search", text), el("label", {}, "Display", display),
    el("label", {}, "Sort by", sort), el("span", { id: "filter-count", class: "muted", "aria-live": "polite" }));
  const wrap = $("jobs").closest(".table-wrap") || $("jobs");
  wrap.before(box);
  wrap.after(el("p", { id: "jobs-none-match", class: "muted", hidden: true }, "No loaded job matches the filters."));
  stateSel.value = choice.state;
  text.value = choice.text;
  sort.value = SORTS.some(([v]) => v === choice.sort) ? choice.sort : "created";
  const changed = () => {
    Object.assign(choice, { state: stateSel.value, text: text.value, display: display.value, sort: sort.value });
    save();
    applyJobFilters();
  };
  for (const c of [stateSel, display, sort]) c.addEventListener("change", changed);
  text.addEventListener("input", changed);
  return box;
}

// The display filter's options: every display the loaded jobs name, and the chosen one even when none does
// now (a refresh must not drop the choice).
function displayOptions(jobs) {
  const sel = $("filter-display");
  const names = [...new Set(jobs.map((j) => j.display).filter(Boolean))].sort();
  if (choice.display && choice.display !== NO_DISPLAY && !names.includes(choice.display)) names.push(choice.display);
  const want = ["", NO_DISPLAY, ...names];
  const have = [...sel.options].map((o) => o.value);
  if (want.join("\n") !== have.join("\n")) {
    sel.replaceChildren(el("option", { value: "" }, "all displays"), el("option", { value: NO_DISPLAY }, "no display"),
      ...names.map((n) => el("option", { value: n }, n)));
  }
  sel.value = choice.display;
}

function sceneEntry(job) {
  const sc = state.scenes.get(job.scene_id);
  return sc && sc.entry ? sc.entry : "";
}

function matches(job) {
  if (choice.state && job.state !== choice.state) return false;
  if (choice.display === NO_DISPLAY ? !!job.display : choice.display && job.display !== choice.display) return false;
  const words = choice.text.trim().toLowerCase().split(/\s+/).filter(Boolean);
  if (!words.length) return true;
  const hay = [jobName(job), job.id, job.scene_id, sceneEntry(job)].join(" ").toLowerCase();
  return words.every((w) => hay.includes(w));
}

const created = (j) => Date.parse(j.created_at) || 0;

function compare(a, b) {
  const newest = created(b) - created(a);
  switch (choice.sort) {
    case "name":
      return jobName(a).localeCompare(jobName(b), undefined, { sensitivity: "base", numeric: true }) || newest;
    case "state":
      return (STATE_ORDER[a.state] ?? 9) - (STATE_ORDER[b.state] ?? 9) || newest;
    case "runtime": {
      // jobs that have not run (queued, cancelled before they started) after every job that has
      const ra = actualSeconds(a), rb = actualSeconds(b);
      if (ra === null || rb === null) return (ra === null) - (rb === null) || newest;
      return rb - ra || newest;
    }
    default:
      return newest;
  }
}

// Hide the rows the filters leave out and put the rest in the chosen order. Called after every list load;
// a row the list replaces later (live progress, a thumbnail) is seen by the observer and placed again.
export function applyJobFilters() {
  const body = $("jobs").tBodies[0];
  controls();
  const rows = [...body.rows];
  const jobs = rows.map((r) => state.jobs.get(r.dataset.jobId)).filter(Boolean);
  displayOptions(jobs);
  applying = true;
  try {
    const keyed = rows.map((r) => ({ r, j: state.jobs.get(r.dataset.jobId) }));
    keyed.sort((a, b) => (a.j && b.j ? compare(a.j, b.j) : 0));
    let shown = 0;
    for (const { r, j } of keyed) {
      r.hidden = !(j && matches(j));
      if (!r.hidden) shown++;
    }
    if (keyed.some(({ r }, i) => body.rows[i] !== r)) body.append(...keyed.map(({ r }) => r));
    const filtering = choice.state || choice.display || choice.text.trim();
    setText($("filter-count"), filtering ? `${shown} of ${rows.length} shown` : "");
    $("jobs-none-match").hidden = !(rows.length && !shown);
  } finally {
    observer && observer.takeRecords();
    applying = false;
  }
  if (!observer) {
    observer = new MutationObserver(() => { if (!applying) applyJobFilters(); });
    observer.observe(body, { childList: true });
  }
}

// ---- the queue's line ------------------------------------------------------------------------------------
function queueWords(q) {
  const j = q.jobs, w = q.workers, p = q.planner;
  const waiting = `Queue: ${j.queued} waiting (${j.queued_yours} yours)`;
  const workers = w.running_here
    ? `workers (${w.engine}): ${w.busy_slots} of ${w.slots} slot${w.slots === 1 ? "" : "s"} busy`
      + (w.alive === false ? ", not responding" : "")
    : `workers (${w.engine}): not in this server, ${j.running} running`;
  const planner = p.state === "stopped" ? "planner: not in this server"
    : p.pending_scenes ? `planner: ${p.pending_scenes} scene${p.pending_scenes === 1 ? "" : "s"} to plan`
      + (p.pending_scenes_yours ? ` (${p.pending_scenes_yours} yours)` : "")
    : "planner: idle";
  return `${waiting} · ${workers} · ${planner}`;
}

export async function refreshQueue() {
  let line = $("queue-line");
  if (!line) {
    line = el("p", { id: "queue-line", class: "queue-line muted", "aria-live": "polite" });
    controls().before(line);
  }
  try {
    setText(line, queueWords(await getJSON("/v1/queue")));
    line.classList.remove("error");
  } catch (err) {
    setText(line, `Queue: could not ask (${err.message})`);
    line.classList.add("error");
  }
}
