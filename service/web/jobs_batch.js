// The job list's batch actions: a tick box per row and one over the shown rows, then Cancel selected, Delete
// selected and Compare selected under the list (selection.js, as on a sweep's page). The ticks live in
// state.ticked, so they survive the list's redraws (live progress, the reload every 10 s).

import { $ } from "./dom.js";
import { refreshHome } from "./jobs_list.js";
import { cancelJob, compareHash, deleteJob, eachJob, secondClick, selectionActions, showSelection, skippedWords,
         tickedIds } from "./selection.js";
import { plural, state } from "./state.js";

const BUTTONS = { cancel: "jobs-cancel-selected", remove: "jobs-delete-selected", compare: "jobs-compare-selected",
                  count: "jobs-selected" };

function shownBoxes() { return [...$("jobs").tBodies[0].querySelectorAll("tr:not([hidden]) input.pick")]; }

function selectedJobs() { return tickedIds($("jobs")).map((id) => state.jobs.get(id)).filter(Boolean); }

// The buttons and the "select all shown" box after any change of the ticks, the rows or the filters.
export function showJobsSelection() {
  if (!$("jobs-select-all")) return;
  const may = !!(state.me && state.me.may_submit);  // a read-only token cancels and deletes nothing
  $(BUTTONS.cancel).hidden = !may; $(BUTTONS.remove).hidden = !may;
  showSelection(selectedJobs(), BUTTONS);
  const boxes = shownBoxes();
  const ticked = boxes.filter((b) => b.checked).length;
  const all = $("jobs-select-all");
  all.checked = boxes.length > 0 && ticked === boxes.length;
  all.indeterminate = ticked > 0 && ticked < boxes.length;
}

function ticked(ev) {
  const box = ev.target;
  if (box.id === "jobs-select-all") {
    for (const b of shownBoxes()) {
      b.checked = box.checked;
      if (box.checked) state.ticked.add(b.value); else state.ticked.delete(b.value);
    }
  } else if (box.classList && box.classList.contains("pick")) {
    if (box.checked) state.ticked.add(box.value); else state.ticked.delete(box.value);
  }
  showJobsSelection();
}

async function act(which) {
  const jobs = selectedJobs();
  const can = selectionActions(jobs);
  if (which === "cancel") {
    await eachJob(can.cancel.map((j) => j.id), cancelJob, "Cancelled",
                  skippedWords(jobs, can.cancel, "already finished"));
  } else {
    const ask = `Click again to delete ${plural(can.remove.length, "finished job")} and their files`;
    if (!secondClick($(BUTTONS.remove), ask)) return;
    await eachJob(can.remove.map((j) => j.id), deleteJob, "Deleted",
                  skippedWords(jobs, can.remove, "not finished (cancel them first)"));
    for (const j of can.remove) state.ticked.delete(j.id);
  }
  await refreshHome();
}

export function initJobsBatch() {
  $("jobs").addEventListener("change", ticked);
  // a filter's change hides or shows ticked rows: the buttons count the shown ones only (a tick box's own input
  // event, which comes before its change, is left to `ticked`)
  const card = $("jobs").closest("section");
  for (const kind of ["change", "input"]) {
    card.addEventListener(kind, (ev) => { if (!$("jobs").contains(ev.target)) showJobsSelection(); });
  }
  $(BUTTONS.cancel).addEventListener("click", () => act("cancel"));
  $(BUTTONS.remove).addEventListener("click", () => act("delete"));
  $(BUTTONS.compare).addEventListener("click", () => {
    const jobs = selectedJobs();
    if (selectionActions(jobs).compare) location.hash = compareHash(jobs.map((j) => j.id));
  });
}
