// A job's evaluation against ground truth (the job asked for it: "Evaluate against ground truth" in the form),
// on its page under the pictures: at the depth the focal sweep's focus slider selects, the hologram's view as it
// was scored beside the Mitsuba thin-lens ground truth through the same pupil, with that depth's PSNR and SSIM;
// a table of every depth and of the view grid, and the viewer-faithful score where the job has one
// (GET /v1/jobs/{id}/evaluation). The slider is the sweep's (job_page.js); this module only listens to it.

import { blobURL, getJSON } from "./api.js";
import { $, clear, el, setText } from "./dom.js";
import { noEvaluation } from "./job_facts.js";
import { aborted, plural, show } from "./state.js";

const num = (v, digits) => (typeof v === "number" && isFinite(v) ? v.toFixed(digits) : "–");
const db = (v) => (typeof v === "number" && isFinite(v) ? `${v.toFixed(2)} dB` : "–");

export function resetEvaluation() {
  show("evaluation", false);
  for (const id of ["eval-focus", "eval-views"]) clear($(id).tBodies[0]);
  for (const id of ["eval-note", "eval-score", "eval-viewer", "eval-focus-label"]) setText($(id), "");
  for (const id of ["eval-holo", "eval-truth"]) { $(id).removeAttribute("src"); delete $(id).dataset.index; }
  show("eval-views-box", false);
}

function viewerLine(v) {
  if (!v) return "";
  const pupils = v.pupils.map((p) => `${num(p.pupil_mm, 1)} mm ${db(p.mean_psnr_db)} (brightness over the eyes `
    + `max/min ${num(p.brightness_max_over_min, 2)}, colour cast ${num(p.colour_cast, 2)})`).join("; ");
  return `Viewer-faithful score: ${db(v.mean_psnr_db)} over ${plural(v.cells, "cell")} (pupils of `
    + `${v.pupils.map((p) => num(p.pupil_mm, 1)).join(" and ")} mm x a ${v.eye_grid}x${v.eye_grid} grid of eye `
    + `positions at ${v.focus_mm.map((z) => num(z, 3)).join(", ")} mm, one brightness scale per colour for all; `
    + `the cells' own best scales spread ${num(v.scale_spread, 2)}x). ${pupils}.`;
}

// The quality the estimate predicted before the job ran, beside what was measured.
function predictedLine(job, v) {
  const q = (job.estimate || {}).quality;
  if (!q || typeof q.psnr_db !== "number") return "";
  const off = typeof v.mean_psnr_db === "number" ? ` (measured ${(v.mean_psnr_db - q.psnr_db >= 0 ? "+" : "")}`
    + `${(v.mean_psnr_db - q.psnr_db).toFixed(1)} dB from it)` : "";
  return ` Predicted before the job ran: ${q.psnr_db.toFixed(1)} dB ±${q.uncertainty_db}${off}.`;
}

export async function showEvaluation(job, page) {
  if (!(job.options || {}).evaluate) return;
  show("evaluation", true);
  const none = noEvaluation(job);
  if (none) {  // the render said why there is none: nothing to ask the service for
    setText($("eval-note"), none.charAt(0).toUpperCase() + none.slice(1));
    return;
  }
  setText($("eval-note"), "Loading the evaluation…");
  let idx;
  try {
    idx = await getJSON(`/v1/jobs/${encodeURIComponent(job.id)}/evaluation`, { signal: page.abort.signal });
  } catch (err) {
    if (aborted(err)) throw err;
    setText($("eval-note"), err.message);
    return;
  }
  const keep = (u) => { page.urls.push(u); return u; };
  const focus = idx.focus;
  const urls = await Promise.all(focus.map(async (f) => (f.skipped ? null : {
    truth: keep(await blobURL(f.truth_url, { signal: page.abort.signal })),
    holo: keep(await blobURL(f.hologram_url, { signal: page.abort.signal })),
  })));
  if (page.abort.signal.aborted) return;
  setText($("eval-note"), `The hologram's simulated view and the Mitsuba thin-lens ground truth (${idx.gt_spp} samples `
    + `per pixel) through a ${num(idx.pupil_mm, 2)} mm pupil, the largest inside every colour's recording cone `
    + `at views ±${idx.view_deg}° (the sweep above uses 4 mm); one least-squares brightness scale per view, both `
    + `at one white level; the border the SLM's aperture vignettes is left out of the score. Mean over the cells: `
    + `PSNR ${db(idx.mean_psnr_db)}, SSIM ${num(idx.mean_ssim, 3)}.`
    + (idx.notes.length ? ` ${idx.notes.join("; ")}.` : ""));
  setText($("eval-viewer"), idx.viewer ? viewerLine(idx.viewer) + predictedLine(job, idx.viewer)
    : idx.viewer_error ? `No viewer-faithful score: ${idx.viewer_error}` : "");

  const slider = $("focus");
  // the sweep's pictures set the slider up; without them (their step failed) it walks the evaluation's depths
  if (Number(slider.max) !== focus.length - 1) {
    slider.max = String(focus.length - 1);
    slider.value = String(Math.floor((focus.length - 1) / 2));
  }
  const rows = clear($("eval-focus").tBodies[0]);
  for (const f of focus) {
    const tr = el("tr", { "data-index": String(f.index) },
      el("td", { class: "num" }, num(f.z_mm, 3)), el("td", {}, f.words),
      el("td", { class: "num" }, f.skipped ? "–" : num(f.psnr_db, 2)),
      el("td", { class: "num" }, f.skipped ? "–" : num(f.ssim, 3)), el("td", { class: "muted" }, f.skipped || ""));
    tr.addEventListener("click", () => {
      slider.value = String(f.index);
      slider.dispatchEvent(new Event("input"));
    });
    rows.append(tr);
  }
  const showFocus = () => {
    const i = Math.min(Math.max(0, Number(slider.value)), focus.length - 1);
    const f = focus[i];
    for (const tr of rows.rows) tr.classList.toggle("current", tr.dataset.index === String(f.index));
    setText($("eval-focus-label"), `at ${num(f.z_mm, 3)} mm from the SLM (${f.words})`);
    for (const [id, key] of [["eval-holo", "holo"], ["eval-truth", "truth"]]) {
      const img = $(id);
      if (urls[i]) img.src = urls[i][key]; else img.removeAttribute("src");
      img.dataset.index = String(f.index);
    }
    setText($("eval-score"), f.skipped ? `No score at this depth: ${f.skipped}.`
      : `PSNR ${db(f.psnr_db)}, SSIM ${num(f.ssim, 3)}`);
  };
  slider.addEventListener("input", showFocus, { signal: page.abort.signal });
  showFocus();

  const views = clear($("eval-views").tBodies[0]);
  for (const v of idx.view_grid) {
    views.append(el("tr", {}, el("td", {}, `${v.col}, ${v.row}`),
      el("td", { class: "num" }, `${num(v.offset_mm[0], 3)}, ${num(v.offset_mm[1], 3)}`),
      el("td", { class: "num" }, num(v.psnr_db, 2)), el("td", { class: "num" }, num(v.ssim, 3))));
  }
  show("eval-views-box", idx.view_grid.length > 0);
  if (idx.view_grid.length) {
    setText($("eval-views-caption"), `The ${idx.views}x${idx.views} view grid (±${idx.view_deg}°), focused at `
      + `${num(idx.view_grid[0].focus_mm, 3)} mm; column, row from the top left.`);
  }
}
