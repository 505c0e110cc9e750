// Re-run with changes: the form takes a job's scene, its optics (as a "profile" of its own) and every option it
// was made with.

import { getJSON } from "./api.js";
import { $, el, setText } from "./dom.js";
import { jobName } from "./job_facts.js";
import { plural, show, state } from "./state.js";
import { estimateSoon, forgetScene, showScene, waitForPlan } from "./submit_form.js";

export async function prefillRerun(job) {
  forgetScene();
  const sc = await getJSON(`/v1/scenes/${encodeURIComponent(job.scene_id)}`);
  state.scenes.set(sc.id, sc);
  state.scene = sc;
  state.rerun = job;
  showScene(sc);
  const o = job.options || {};
  const optics = o.optics || {};
  const sel = $("profile");
  sel.prepend(el("option", { value: `job:${job.id}` }, `as job ${jobName(job)} (${(optics.resolution_hw || []).join("x")}, `
    + `${optics.pitch_um} µm, ${plural((optics.wavelengths_nm || []).length, "color")})`));
  sel.value = `job:${job.id}`;
  $("res-h").value = optics.resolution_hw[0];
  $("res-w").value = optics.resolution_hw[1];
  $("scene-scale").value = optics.scene_scale && optics.scene_scale !== 1 ? optics.scene_scale : "";
  // every option the job was made with, as it was stored: submitted unchanged, the job comes out the same
  $("frames").value = o.frames ?? optics.frames;
  $("preset").value = o.preset;
  $("encoder").value = o.encoder;
  $("optimiser").value = o.optimiser || "lbfgs";
  $("method").value = o.method || "wrp";
  $("time-limit").value = o.render_time_limit_s ?? "";
  $("spp").value = o.spp ?? "";  // a time-limited job's is its cap of rays per pixel
  $("iterations").value = o.iterations ?? "";
  $("quality-db").value = "";  // a target was resolved into the options above when the job was made
  $("wrp-planes").value = String(o.wrp_planes ?? "auto");
  $("evaluate").checked = !!o.evaluate;
  $("display").value = job.display || "";
  $("job-name").value = `${jobName(job)} (re-run)`.slice(0, 120);
  setText($("rerun-note"), `Re-run of job ${jobName(job)} (${job.id}) on its scene: change what you want and submit.`);
  show("rerun-note", true);
  show("job-form", true);
  $("submit").scrollIntoView();
  if (sc.plan_state !== "ready" && sc.plan_state !== "failed") waitForPlan(sc.id);
  estimateSoon();
}


// No estimate goes out after this (signing out), and none that was out comes back in.
