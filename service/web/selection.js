// Jobs ticked in a table (the home page's list, a sweep's page) and what may be done with them: Cancel selected
// (the unfinished ones), Delete selected (the finished ones, after a second click), Compare selected (2 to 4
// succeeded jobs). One copy for both pages, so they ask, skip and report the same way.

import { request } from "./api.js";
import { el, setText } from "./dom.js";
import { FINAL, plural, status } from "./state.js";

export const COMPARE_MOST = 4; // the compare page's columns
const ARMED_MS = 5000;

// A row's tick box; `ticked` is the selection the table keeps across its redraws.
export function tickBox(id, ticked) {
  const box = el("input", { type: "checkbox", class: "pick", value: id, "aria-label": `select ${id}` });
  box.checked = ticked.has(id);
  return box;
}

// The ids ticked in `table`'s shown rows, in the table's order (a row a filter hides is not acted on).
export function tickedIds(table) {
  return [...table.tBodies[0].querySelectorAll("tr:not([hidden]) input.pick:checked")].map((b) => b.value);
}

// What each button may do with the ticked jobs (`jobs`: their records, each with id and state).
export function selectionActions(jobs) {
  return {
    cancel: jobs.filter((j) => !FINAL.has(j.state)),
    remove: jobs.filter((j) => FINAL.has(j.state)),
    compare: jobs.length >= 2 && jobs.length <= COMPARE_MOST && jobs.every((j) => j.state === "succeeded"),
  };
}

// The buttons' states and the count beside them; `ids` maps each button's role to its element id.
export function showSelection(jobs, ids) {
  const can = selectionActions(jobs);
  document.getElementById(ids.cancel).disabled = !can.cancel.length;
  document.getElementById(ids.remove).disabled = !can.remove.length;
  document.getElementById(ids.compare).disabled = !can.compare;
  const words = !jobs.length ? "" : `${plural(jobs.length, "job")} selected`
    + (jobs.length > COMPARE_MOST ? ` (compare takes ${COMPARE_MOST} at most)` : "");
  setText(document.getElementById(ids.count), words);
}

export const cancelJob = (id) => request(`/v1/jobs/${encodeURIComponent(id)}`, { method: "DELETE" });
export const deleteJob = (id) => request(`/v1/jobs/${encodeURIComponent(id)}/delete`, { method: "POST" });

// The line naming the ticked jobs a button leaves alone, and why ("" when it leaves none).
export function skippedWords(jobs, kept, why) {
  const ids = new Set(kept.map((j) => j.id));
  const left = jobs.filter((j) => !ids.has(j.id));
  if (!left.length) return "";
  const shown = left.slice(0, 3).map((j) => j.id).join(", ") + (left.length > 3 ? ", ..." : "");
  return `skipped ${plural(left.length, "job")} (${shown}): ${why}`;
}

// Runs `act` on each id in turn, then says in one line how many it did, which it skipped and why, and the
// first refusal.
export async function eachJob(ids, act, words, skipped = "") {
  let ok = 0, first = null;
  for (const id of ids) {
    try { await act(id); ok++; } catch (err) { first = first || `${id}: ${err.message}`; }
  }
  status(`${words} ${plural(ok, "job")}` + (skipped ? `; ${skipped}` : "") + (first ? `; not all: ${first}` : ""),
         !!first);
}

// A delete asks twice: the first click arms the button for five seconds with `ask` as its words; true on the
// second click.
export function secondClick(btn, ask) {
  if (!btn.dataset.armed) {
    btn.dataset.armed = "1";
    btn.dataset.label = btn.dataset.label || btn.textContent;
    setText(btn, ask);
    btn.armTimer = setTimeout(() => disarm(btn), ARMED_MS);
    return false;
  }
  disarm(btn);
  return true;
}

function disarm(btn) {
  clearTimeout(btn.armTimer);
  delete btn.dataset.armed;
  if (btn.dataset.label) setText(btn, btn.dataset.label);
}

// Cancel Selected or Delete Selected (``which``: "cancel" or "remove") on the ticked ``jobs``; Delete asks for a
// second click on ``button`` first. Returns the jobs it deleted ([] for Cancel), or null while Delete waits.
export async function actOnSelected(which, jobs, button) {
  const can = selectionActions(jobs);
  if (which === "cancel") {
    await eachJob(can.cancel.map((j) => j.id), cancelJob, "Cancelled",
                  skippedWords(jobs, can.cancel, "already finished"));
    return [];
  }
  if (!secondClick(button, `Click again to delete ${plural(can.remove.length, "finished job")} and their files`)) {
    return null;
  }
  await eachJob(can.remove.map((j) => j.id), deleteJob, "Deleted",
                skippedWords(jobs, can.remove, "not finished (cancel them first)"));
  return can.remove;
}

export const compareHash = (ids) => `#/compare/${ids.join("/")}`;
