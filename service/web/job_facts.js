// A job's facts as the list and the job page show them: its name, options, the progress shown (never moving
// backwards) and what is left of it.

import { fmtSeconds } from "./dom.js";
import { plural, state } from "./state.js";

// The fraction shown for a job: the largest one shown so far (a step's progress file starting over, or a
// restarted stream, never moves the bar back); 1 once it has succeeded.
export function pct(job) {
  if (job.state === "succeeded") return 1;
  const f = job.progress && typeof job.progress.fraction === "number" ? job.progress.fraction : 0;
  const p = Math.max(state.shown.get(job.id) || 0, Math.max(0, Math.min(1, f)));
  if (job.state === "running") state.shown.set(job.id, p);
  return p;
}

// What is left, from the estimate: its seconds less the time run so far, or (past the estimate) the time run so
// far scaled by the fraction still to do.
export function eta(job) {
  const est = job.estimate && typeof job.estimate.seconds === "number" ? job.estimate.seconds : null;
  if (job.state === "queued") return est === null ? "waiting for a worker" : `waiting for a worker; about ${fmtSeconds(est)} once it starts`;
  if (job.state !== "running" || est === null || !job.started_at) return "";
  const ran = Math.max(0, (Date.now() - Date.parse(job.started_at)) / 1000);
  const p = pct(job);
  if (ran < est) return `about ${fmtSeconds(est - ran)} left`;
  if (p > 0.05) return `about ${fmtSeconds(ran * (1 - p) / p)} left (past the estimate of ${fmtSeconds(est)})`;
  return `past the estimate of ${fmtSeconds(est)}`;
}

export function jobName(job) {
  if (job.name) return job.name;
  const sc = state.scenes.get(job.scene_id);
  return sc ? sc.entry : job.scene_id;
}

export function optionsText(job) {
  const o = job.options || {};
  const optics = o.optics || {};
  const res = (optics.resolution_hw || []).join("x");
  return [res && `${res} px`, typeof optics.frames === "number" ? plural(optics.frames, "frame") : null,
          o.preset, o.encoder, o.render_time_limit_s ? `${fmtSeconds(o.render_time_limit_s)} limit` : null,
          o.spp && !o.render_time_limit_s ? `${o.spp} rays/px` : null, o.evaluate ? "evaluated" : null]
    .filter(Boolean).join(" · ");
}

export function actualSeconds(job) {
  const t = job.timings || {};
  if (typeof t.run_s === "number") return t.run_s;
  if (job.state === "running" && job.started_at) return (Date.now() - Date.parse(job.started_at)) / 1000;
  return null;
}
