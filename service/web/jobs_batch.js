// The job list's batch actions: a tick box per row and one over the shown rows, then Cancel selected, Delete
// selected and Compare selected under the list (selection.js, as on a sweep's page). The ticks live in
// state.ticked, so they survive the list's redraws (live progress, the reload every 10 s).

import { $ } from "./dom.js";
import { refreshHome } from "./jobs_list.js";
import { actOnSelected, compareHash, selectionActions, showSelection, tickedIds } from "./selection.js";
import { state } from "./state.js";

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
  const removed = await actOnSelected(which, selectedJobs(), $(BUTTONS.remove));
  if (removed === null) return;  // Delete waits for its second click
  for (const j of removed) state.ticked.delete(j.id);
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
