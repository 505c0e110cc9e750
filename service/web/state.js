// What the page's modules share: the session's state, the job states that are final, and small helpers.

import { $, setText } from "./dom.js";

export const FINAL = new Set(["succeeded", "failed", "cancelled"]);
export const MAX_STREAMS = 4; // live event streams at once (a browser holds ~6 connections per host)

export const state = {
  me: null,
  profiles: null,
  optionLimits: null, // each job option's allowed values on this service (GET /v1/job-options)
  scenes: new Map(), // scene id -> scene (entry name for the lists)
  jobs: new Map(),
  streams: new Map(), // job id -> AbortController (job list streams)
  page: null, // {id, abort, urls}
  scene: null, // the scene uploaded in the form
  rerun: null, // the job whose options the form holds (re-run with changes)
  rerunPending: null, // the job the Re-run button asked for, taken by the next visit to the home page
  timer: null,
  shown: new Map(), // job id -> the largest fraction shown: progress never moves backwards on the page
  thumbs: new Map(), // job id -> object URL of its preview (the list's thumbnails)
  ticked: new Set(), // the job list's ticked rows, kept while rows are redrawn (live progress, reloads)
};

export const plural = (n, one, many = `${one}s`) => `${n} ${n === 1 ? one : many}`;
export const aborted = (err) => err && err.name === "AbortError";

export function status(text, isError = false) {
  const s = $("status");
  setText(s, text);
  s.classList.toggle("error", isError);
}

export function show(id, visible) { $(id).hidden = !visible; }
