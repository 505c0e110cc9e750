// A job's facts as the list and the job page show them: its name, options, the progress shown (never moving
// backwards) and what is left of it.

import { el, fmtSeconds } from "./dom.js";
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

// The seconds an estimate expects at the machine's load when it was made (its idle-machine seconds when it
// says no load).
export function expectedSeconds(est) {
  if (!est) return null;
  if (typeof est.seconds_at_load === "number") return est.seconds_at_load;
  return typeof est.seconds === "number" ? est.seconds : null;
}

// How the machine's load moved an estimate: "" on an idle machine.
export function loadText(est) {
  const l = est && est.load;
  if (!l || typeof l.slowdown !== "number" || l.slowdown < 1.2) return "";
  return `${fmtSeconds(est.seconds_at_load)} at the machine's present load (${l.others.toFixed(1)} other `
    + `threads on ${l.cores} cores: ${l.slowdown.toFixed(1)}x), ${fmtSeconds(est.seconds)} on an idle one`;
}

// What is left. With the job's live view (its steps' estimates, the pace its finished steps measured and the
// running step's own pace: the server's left_s) that; else the estimate (at the load it was made at) less the
// time run so far, blended, as the run goes, into the pace measured so far; past the estimate, the pace.
export function eta(job, live = null) {
  const est = expectedSeconds(job.estimate);
  if (job.state === "queued") return est === null ? "waiting for a worker" : `waiting for a worker; about ${fmtSeconds(est)} once it starts`;
  if (job.state !== "running") return "";
  const ran = actualSeconds(job, live);
  if (live && live.state === "running" && typeof live.left_s === "number") {
    return `about ${fmtSeconds(live.left_s)} left` + (est !== null && ran !== null && ran + live.left_s > 1.5 * est
      ? ` (the estimate was ${fmtSeconds(est)}; this run goes slower)` : "");
  }
  if (est === null || ran === null) return "";
  const p = pct(job);
  const pace = p > 0.05 ? ran * (1 - p) / p : null;
  if (ran < est) return `about ${fmtSeconds(pace === null ? est - ran : p * pace + (1 - p) * (est - ran))} left`;
  if (pace !== null) return `about ${fmtSeconds(pace)} left (past the estimate of ${fmtSeconds(est)})`;
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
          o.spp && !o.render_time_limit_s ? `${o.spp} rays/px` : null, evaluationWord(job)]
    .filter(Boolean).join(" · ");
}

// The seconds the job has run: its run's (timings.run_s); while it runs, since it started (or what its live view
// counted); a job stopped before it finished, from its start to its end.
export function actualSeconds(job, live = null) {
  const t = job.timings || {};
  if (typeof t.run_s === "number") return t.run_s;
  if (job.state === "running" && job.started_at) return Math.max(0, (Date.now() - Date.parse(job.started_at)) / 1000);
  if (job.started_at && job.finished_at) {
    return Math.max(0, (Date.parse(job.finished_at) - Date.parse(job.started_at)) / 1000);
  }
  if (live && typeof live.elapsed_s === "number" && live.state !== "queued") return live.elapsed_s;
  return null;
}

// Why a job that asked for an evaluation has none (its render's warning, "no evaluation ..."), else null.
export function noEvaluation(job) {
  if (!(job.options || {}).evaluate) return null;
  const warnings = (job.plan && !job.plan.source && job.plan.warnings) || [];
  return warnings.find((w) => typeof w === "string" && /^no evaluation\b/i.test(w)) || null;
}

// What the list says of a job's evaluation: only a job that made one is "evaluated".
function evaluationWord(job) {
  if (!(job.options || {}).evaluate) return null;
  if (noEvaluation(job)) return "no evaluation";
  return job.state === "succeeded" ? "evaluated" : job.state === "queued" || job.state === "running"
    ? "to be evaluated" : null;
}

// The flag on a result too poor to be useful: the job's viewer-faithful PSNR (the API's `quality`: measured once
// evaluated, else predicted) below the service's one level for it (`quality.floor_db`). `long` gives the
// words in full (the job page), else a short badge with the words in its title (the list). Null when it is fine.
export function lowQualityFlag(job, long = false) {
  const q = job.quality;
  if (!q || !q.too_low) return null;
  const measured = q.source === "measured";
  const words = `${measured ? "measured" : "predicted"} ${q.psnr_db.toFixed(1)} dB viewer-faithful PSNR, below `
    + `the ${q.floor_db} dB under which a hologram shows speckle and bands rather than the scene`;
  return el("span", { class: "badge low-quality", title: words, dataset: { source: q.source } },
    long ? `Quality too low to be useful: ${words}` : measured ? "quality too low" : "quality likely too low");
}
