// A finished job's phase frames, one frame and colour at a time (the 8-bit grey patterns the SLM shows), and
// "Send to display": make the job the one a display of its owner shows next, with what each display shows now
// (from its agent's heartbeats).

import { blobURL, getJSON, request } from "./api.js";
import { $, clear, el, fmtTime, setText } from "./dom.js";
import { aborted, plural, show, state } from "./state.js";

const DISPLAYS_POLL_MS = 2000; // an agent heartbeats every few seconds and polls for its next job as often

const nm = (w) => `${Number(w.toFixed(1))} nm`;

// Everything the section and the send box show, emptied (the job page calls it before each job).
export function resetPhaseFrames() {
  clear($("phase-card"));
  clear($("job-send"));
  show("phase-card", false);
  show("job-send", false);
}

// The "Phase frames" section: a frame slider with its number box, a button per colour, the grey image at the
// SLM's own aspect ratio and "frame 3 of 24, 516.5 nm" under it.
export async function showPhaseFrames(job, page) {
  const idx = await getJSON(`/v1/jobs/${encodeURIComponent(job.id)}/phase`, { signal: page.abort.signal });
  if (state.page !== page) return;
  const card = clear($("phase-card"));
  const last = idx.frames - 1;
  const slider = el("input", { id: "phase-frame", type: "range", min: 0, max: last, value: 0, step: 1,
                               "aria-label": "frame" });
  const number = el("input", { id: "phase-frame-num", type: "number", min: 1, max: idx.frames, value: 1, step: 1,
                               "aria-label": "frame number" });
  const colours = el("div", { id: "phase-colours", class: "actions" });
  const img = el("img", { id: "phase-img", class: "phase-img", alt: "phase frame (grey level = phase)",
                          width: idx.width_px, height: idx.height_px });
  img.style.aspectRatio = `${idx.width_px} / ${idx.height_px}`;
  const label = el("figcaption", { id: "phase-label" });
  card.append(
    el("h2", {}, "Phase frames"),
    el("p", { class: "muted", id: "phase-note" }, `What the SLM shows: ${plural(idx.frames, "frame")} × `
      + `${plural(idx.colours.length, "colour")}, ${idx.height_px}x${idx.width_px} px; grey level 0..`
      + `${idx.levels_per_2pi - 1} is phase 0..2π.`),
    el("div", { class: "phase-controls" },
       el("label", { class: "inline" }, "Frame", slider, number), colours),
    el("figure", { class: "phase" }, img, label));
  show("phase-card", true);

  const urls = new Map(); // "f/c" -> object URL (revoked with the page's)
  let frame = 0, colour = 0, want = 0;
  const draw = async () => {
    const ask = ++want;
    const key = `${frame}/${colour}`;
    const c = idx.colours[colour];
    for (const b of colours.querySelectorAll("button")) b.classList.toggle("active", Number(b.dataset.colour) === colour);
    slider.value = String(frame);
    number.value = String(frame + 1);
    try {
      if (!urls.has(key)) {
        const path = idx.frame_url.replace("{frame}", String(frame)).replace("{colour}", String(colour));
        const url = await blobURL(path, { signal: page.abort.signal });
        page.urls.push(url);
        urls.set(key, url);
      }
    } catch (err) {
      if (!aborted(err) && ask === want) setText(label, `Could not load frame ${frame + 1}: ${err.message}`);
      return;
    }
    if (ask !== want || state.page !== page) return; // a later choice came first
    img.src = urls.get(key);
    img.dataset.frame = String(frame);
    img.dataset.colour = String(colour);
    setText(label, `frame ${frame + 1} of ${idx.frames}, ${nm(c.wavelength_nm)}`);
  };
  for (const c of idx.colours) {
    const b = el("button", { type: "button", class: "small", "data-colour": c.index }, `${c.name} ${nm(c.wavelength_nm)}`);
    b.addEventListener("click", () => { colour = c.index; draw(); });
    colours.append(b);
  }
  slider.addEventListener("input", () => { frame = Number(slider.value); draw(); });
  number.addEventListener("change", () => {
    const n = Math.round(Number(number.value));
    if (!Number.isFinite(n)) { number.value = String(frame + 1); return; }
    frame = Math.min(last, Math.max(0, n - 1));
    draw();
  });
  await draw();
}

// "Send to display": the owner's displays to choose from (a token that may submit), and what each shows now,
// refreshed while the page is open.
export async function offerSend(job, page) {
  const box = clear($("job-send"));
  const may = !!(state.me && state.me.may_submit);
  const pick = el("select", { id: "send-display", "aria-label": "display" });
  const go = el("button", { type: "button", id: "send-go", class: "secondary" }, "Send to display");
  const note = el("span", { id: "send-note", class: "muted" });
  const list = el("ul", { id: "display-showing", class: "showing" });
  if (may) box.append(el("div", { class: "actions" }, el("label", { class: "inline" }, "Send to", pick), go, note));
  box.append(list);

  const describe = (d) => {
    const s = d.showing;
    if (!s) return `${d.name} shows nothing${d.state ? ` (${d.state})` : ""}`;
    if (s.job_id === job.id) return `${d.name} shows this job, frame ${s.frame + 1}`;
    return [`${d.name} shows job `, el("a", { href: `#/jobs/${encodeURIComponent(s.job_id)}` }, s.job_id)];
  };
  const refresh = async () => {
    const { displays } = await getJSON("/v1/displays", { signal: page.abort.signal });
    if (state.page !== page) return;
    const chosen = pick.value;
    const names = displays.map((d) => d.name);
    if (names.join("\n") !== [...pick.options].map((o) => o.value).join("\n")) {
      clear(pick).append(...names.map((n) => el("option", { value: n }, n)));
      if (names.includes(chosen)) pick.value = chosen;
      else if (names.includes(job.display)) pick.value = job.display;
    }
    go.disabled = names.length === 0;
    clear(list);
    for (const d of displays) {
      list.append(el("li", { "data-display": d.name, class: d.showing && d.showing.job_id === job.id ? "this-job" : "" },
                     describe(d), el("span", { class: "muted" }, ` · last seen ${fmtTime(d.last_seen)}`)));
    }
    if (!displays.length) list.append(el("li", { class: "muted" }, "No display has sent a heartbeat yet: a display "
      + "appears here once its agent runs."));
  };
  go.addEventListener("click", async () => {
    const name = pick.value;
    if (!name) return;
    go.disabled = true;
    try {
      const sent = await (await request(`/v1/jobs/${encodeURIComponent(job.id)}/display`,
                                        { method: "POST", json: { display: name }, signal: page.abort.signal })).json();
      if (state.page !== page) return;
      note.classList.remove("error");
      setText(note, `Sent to ${sent.display} at ${fmtTime(sent.sent_at)}: it switches at its agent's next poll.`);
    } catch (err) {
      if (aborted(err)) return;
      note.classList.add("error");
      setText(note, `Not sent: ${err.message}`);
    }
    go.disabled = false;
    refresh().catch(() => {});
  });
  show("job-send", true);
  await refresh();
  const timer = setInterval(() => { refresh().catch(() => {}); }, DISPLAYS_POLL_MS);
  page.abort.signal.addEventListener("abort", () => clearInterval(timer));
}
