// What a job is doing, on its page (GET /v1/jobs/{id}/live, and the live event of its stream, every second while
// it runs): the step timeline (estimated against actual seconds, the running step marked), the worker's CPU and
// memory, and the running step's last log lines in the logs card. The plan it carries is shown by job_page.js.

import { $, clear, el, fmtBytes, fmtSeconds, setText } from "./dom.js";
import { show } from "./state.js";

const STEP_WORDS = { preview: "preview + pictures" };

export function renderLive(live) {
  renderSteps(live);
  const w = live && live.worker;
  setText($("job-worker"), w ? `Worker: ${fmtSeconds(w.cpu_s)} of CPU time, ${fmtBytes(w.rss_bytes)} resident `
    + `memory (${w.processes} ${w.processes === 1 ? "process" : "processes"})` : "");
  renderTail(live);
}

function renderSteps(live) {
  const ol = clear($("steps"));
  for (const s of (live && live.steps) || []) {
    const current = s.step === live.step || s.state === "stopped";
    ol.append(el("li", { class: `step ${s.state}${current ? " current" : ""}`, "data-step": s.step,
                         "aria-current": current ? "step" : null },
      el("span", { class: "step-name" }, STEP_WORDS[s.step] || s.step),
      el("span", { class: "step-times" }, `estimated ${s.estimated_s === null ? "–" : fmtSeconds(s.estimated_s)}`
        + ` · actual ${s.actual_s === null ? "–" : fmtSeconds(s.actual_s)}`
        + (s.state === "running" ? " (running)" : s.state === "stopped" ? " (stopped here)" : ""))));
  }
  show("steps", ol.childElementCount > 0);
}

// While a step runs, the logs card shows its last lines, live; the step's whole log comes when the job ends.
function renderTail(live) {
  const tail = live && live.log;
  if (!tail || live.state !== "running") return;
  show("logs-card", true);
  const tabs = $("log-tabs");
  if (!tabs.querySelector(`[data-live]`)) clear(tabs).append(el("span", { class: "muted", "data-live": "1" }, ""));
  setText(tabs.querySelector("[data-live]"), tail.source === "progress"
    ? `${tail.step}.log is empty so far (it is written at the step's end); its progress, live`
    : `${tail.step}.log, its last ${tail.lines.length} lines, live`);
  const pre = $("log-text");
  const atEnd = pre.scrollTop + pre.clientHeight >= pre.scrollHeight - 4;
  setText(pre, tail.lines.length ? tail.lines.join("\n") : "(nothing yet)");
  pre.dataset.step = tail.step;
  pre.dataset.live = "1";
  if (atEnd) pre.scrollTop = pre.scrollHeight;
}
