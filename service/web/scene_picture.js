// The scene through its own camera (the planner's picture, GET /v1/scenes/{id}/picture.png) with the part the
// hologram shows drawn over it: the server's field_of_view_box, fractions of the picture, at the form's options
// (each estimate brings it) or at a job's. The hologram shows the display's view, 2 atan(W p / 2f), around the
// camera's axis, so a change of resolution or pitch moves the box's edges; a display that sees more than the
// camera gets a box past the picture's edges, clipped there and drawn dashed, and the caption says so.

import { blobURL, getJSON } from "./api.js";
import { $, clear, el, setText } from "./dom.js";

const urls = new Map(); // scene id -> blob: URL of its picture (fetched once per page load)

async function pictureURL(scene) {
  if (!urls.has(scene.id)) urls.set(scene.id, blobURL(scene.picture_url).catch((err) => { urls.delete(scene.id); throw err; }));
  return urls.get(scene.id);
}

// The figure inside `holder` (built once): the picture in a frame, the box over it, a caption under it.
function figure(holder, prefix) {
  let fig = holder.querySelector("figure.scene-picture");
  if (fig) return fig;
  fig = el("figure", { class: "scene-picture", id: `${prefix}-scene-figure` },
    el("div", { class: "scene-frame" },
      el("img", { id: `${prefix}-scene-img`, alt: "the scene through its camera" }),
      el("div", { class: "fov-box", id: `${prefix}-fov-box`, hidden: true })),
    el("figcaption", { id: `${prefix}-fov-caption` }));
  holder.append(fig);
  return fig;
}

function drawBox(fig, box) {
  const div = fig.querySelector(".fov-box");
  const caption = fig.querySelector("figcaption");
  if (!box) {
    div.hidden = true;
    setText(caption, "The hologram's field of view is shown once the scene's plan is ready.");
    return;
  }
  // CSP forbids inline styles in the HTML, not styles set from a script: the box is placed in percentages
  div.style.left = `${(100 * box.x0).toFixed(3)}%`;
  div.style.top = `${(100 * box.y0).toFixed(3)}%`;
  div.style.width = `${(100 * (box.x1 - box.x0)).toFixed(3)}%`;
  div.style.height = `${(100 * (box.y1 - box.y0)).toFixed(3)}%`;
  div.classList.toggle("beyond", !!box.beyond_camera);
  for (const k of ["x0", "y0", "x1", "y1"]) div.dataset[k] = String(box[k]);
  div.hidden = false;
  setText(caption, box.summary.charAt(0).toUpperCase() + box.summary.slice(1));
}

// Show `scene`'s picture in `holder` with `box` over it (null: no box yet). Without a picture (plan pending or
// failed, or a scene planned before pictures were made) the holder says why and holds no figure.
export async function showScenePicture(holder, prefix, scene, box) {
  if (!holder) return;
  if (!scene || !scene.picture_url) {
    clear(holder);
    holder.hidden = !scene || scene.plan_state === "failed";
    if (scene && scene.plan_state !== "failed") {
      holder.append(el("p", { class: "muted", id: `${prefix}-scene-wait` }, scene.plan_state === "ready"
        ? "This scene has no picture (it was planned before the service made them)."
        : "The scene's picture comes with its plan…"));
    }
    return;
  }
  holder.hidden = false;
  const wait = holder.querySelector("p.muted");
  if (wait) wait.remove();
  const fig = figure(holder, prefix);
  drawBox(fig, box);
  const img = fig.querySelector("img");
  if (img.dataset.scene === scene.id) return;
  img.dataset.scene = scene.id;
  try {
    const url = await pictureURL(scene);
    if (img.dataset.scene === scene.id) img.src = url;
  } catch (err) {
    if (img.dataset.scene === scene.id) setText(fig.querySelector("figcaption"), `No picture: ${err.message}`);
  }
}

// The form's picture: the uploaded scene, the box at the options the last estimate was made for.
export function showFormPicture(scene, box) {
  return showScenePicture($("form-scene-picture"), "form", scene, box || (scene && scene.field_of_view_box) || null);
}

// The form's options were refused: no field of view is drawn for them (not the last accepted one's).
export function refuseFormBox() {
  const fig = $("form-scene-picture") && $("form-scene-picture").querySelector("figure.scene-picture");
  if (!fig) return;
  fig.querySelector(".fov-box").hidden = true;
  setText(fig.querySelector("figcaption"), "No field of view: the options are refused (see the estimate).");
}

export function clearFormPicture() {
  const holder = $("form-scene-picture");
  if (holder) { clear(holder); holder.hidden = true; }
}

// Signing out: no picture of one owner's scene stays for the next (its blob: URLs are let go).
export function forgetPictures() {
  for (const u of urls.values()) u.then((url) => URL.revokeObjectURL(url), () => {});
  urls.clear();
  clearFormPicture();
  clearJobPicture();
}

export function clearJobPicture() {
  const holder = $("job-scene-picture");
  if (holder) { clear(holder); holder.hidden = true; }
}

// A job's page: the scene's picture with the box at the job's own optics (GET /v1/jobs/{id} gives it; the
// scene is asked afresh, since a list's copy may predate its plan).
export async function showJobPicture(job, signal) {
  const holder = $("job-scene-picture");
  if (!holder) return;
  clear(holder);
  holder.hidden = true;
  let scene = null;
  try {
    scene = await getJSON(`/v1/scenes/${encodeURIComponent(job.scene_id)}`, { signal });
  } catch (_) { return; } // another owner's scene (an admin's view) or gone: nothing to show
  if (signal && signal.aborted) return;
  await showScenePicture(holder, "job", scene, job.field_of_view_box || null);
}
