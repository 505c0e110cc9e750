// The results page: sign in with a token, then the home page (the job list, the submit form) or one job's page,
// chosen by the URL's hash. Everything the service says is shown with textContent (dom.js); nothing is parsed
// as HTML. The parts: jobs_list.js, submit_form.js, job_page.js, compare.js, sweep.js (state.js holds what
// they share).

import { ApiError, getJSON, setUnauthorizedHandler, token } from "./api.js";
import { $, clear, setText } from "./dom.js";
import { leaveCompare, routeCompare } from "./compare.js";
import { leaveJobPage, showJob } from "./job_page.js";
import { initJobsBatch } from "./jobs_batch.js";
import { refreshHome } from "./jobs_list.js";
import { estimateSoon, initForm, loadProfiles, resetForm } from "./submit_form.js";
import { prefillRerun } from "./rerun_form.js";
import { forgetPictures } from "./scene_picture.js";
import { initSweep, leaveSweep, refreshSweepsLine, showSweep } from "./sweep.js";
import { aborted, show, state, status } from "./state.js";

// ---- sign in / out -------------------------------------------------------------------------------------------
function signedOut(message = "") {
  token.clear();
  state.me = null;
  stopAll();
  forgetUser();
  show("signin", true); show("home", false); show("job", false); show("compare", false); show("sweep", false);
  show("signout", false);
  setText($("who"), "");
  setText($("signin-error"), message);
  $("token").focus();
}

// Everything the page holds for the signed-in owner goes with them: the form, the scenes and jobs it knows, the
// lists, the pictures.
function forgetUser() {
  resetForm();
  forgetPictures();
  for (const u of state.thumbs.values()) if (u) URL.revokeObjectURL(u);
  for (const m of [state.scenes, state.jobs, state.shown, state.thumbs, state.ticked]) m.clear();
  state.rerun = null; state.rerunPending = null;
  for (const id of ["jobs", "displays"]) clear($(id).tBodies[0]);
  clear($("sweeps-line")); show("sweeps-line", false);
  const queue = $("queue-line");
  if (queue) setText(queue, "");
  status("");
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
  leaveCompare();
  leaveSweep();
  if (state.timer) { clearInterval(state.timer); state.timer = null; }
}

function route() {
  if (!state.me) return;
  const m = /^#\/jobs\/([A-Za-z0-9_-]{1,64})$/.exec(location.hash);
  const sw = /^#\/sweeps\/([A-Za-z0-9_-]{1,64})$/.exec(location.hash);
  stopAll();
  show("compare", false); show("sweep", false);
  if (sw) {
    show("home", false); show("job", false); show("sweep", true);
    showSweep(sw[1]).catch((err) => { if (!aborted(err)) status(`Could not show the sweep: ${err.message}`, true); });
  } else if (location.hash.startsWith("#/compare")) {
    show("home", false); show("job", false); show("compare", true);
    if (!routeCompare(location.hash)) status("That compare address names no 2 to 4 jobs.", true);
  } else if (m) {
    show("home", false); show("job", true);
    showJob(m[1]).catch((err) => { if (!aborted(err)) status(`Could not show the job: ${err.message}`, true); });
  } else {
    show("job", false); show("home", true);
    refreshHome(); refreshSweepsLine();
    state.timer = setInterval(refreshHome, 10000);
    const again = state.rerunPending;
    state.rerunPending = null;
    if (again) prefillRerun(again).catch((err) => status(`Could not re-run: ${err.message}`, true));
    else if (state.scene && state.me.may_submit) estimateSoon();  // a read-only token has no form
  }
}

// ---- start ----------------------------------------------------------------------------------------------------
function init() {
  setUnauthorizedHandler(() => signedOut("Signed out: the token is no longer accepted."));
  $("signin-form").addEventListener("submit", signIn);
  $("signout").addEventListener("click", () => signedOut());
  $("refresh").addEventListener("click", () => { refreshHome(); refreshSweepsLine(); });
  initForm();
  initSweep();
  initJobsBatch();
  window.addEventListener("hashchange", route);
  if (token.get()) start().catch(() => signedOut("Please sign in again.")); else signedOut();
}

init();
