// The dashboard: three views over the coordinator's JSON, refreshed every second. No build
// step and no dependencies, so the coordinator serves it as it is.
"use strict";

const main = document.getElementById("main");
const POLL_MS = 1000;

function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") e.className = v;
    else if (k.startsWith("on")) e.addEventListener(k.slice(2), v);
    else e.setAttribute(k, v);
  }
  for (const c of children) e.append(c instanceof Node ? c : String(c));
  return e;
}

async function api(path, opts = {}) {
  const r = await fetch(path, { credentials: "same-origin", ...opts });
  if (r.status === 401) { location.reload(); throw new Error("logged out"); }
  const body = await r.json();
  if (!r.ok) throw new Error(body.error || r.statusText);
  return body;
}

const fmt = {
  pct: (a, b) => (b > 0 ? (100 * a / b) : 0),
  msps: (s) => (s > 0 ? (s / 1e6).toFixed(2) : "–"),
  noise: (r) => (r > 0 ? (100 * r).toFixed(2) + "%" : "–"),
  eta: (s) => {
    if (s == null || s < 0) return "–";
    if (s < 60) return Math.round(s) + " s";
    if (s < 3600) return Math.round(s / 60) + " min";
    return (s / 3600).toFixed(1) + " h";
  },
  count: (n) => n.toLocaleString("en-US"),
  gib: (b) => (b % 2 ** 30 === 0 ? b / 2 ** 30 : (b / 2 ** 30).toFixed(1)) + " GiB",
  ago: (ms) => (ms < 1000 ? "now" : ms < 60000 ? Math.round(ms / 1000) + " s ago" : Math.round(ms / 60000) + " min ago"),
};

function bar(done, total) {
  const p = fmt.pct(done, total);
  return el("span", {}, el("span", { class: "bar" }, el("span", { style: `width:${p.toFixed(1)}%` })), " ", p.toFixed(1) + "%");
}

function stateTag(s) { return el("span", { class: "state " + s }, s); }

function live(s) { return s === "queued" || s === "running"; }

async function release(w) {
  if (!confirm(`Release ${w.name} (${w.worker_id}) from quarantine? Its invalid results are forgotten and it may lease again.`)) return;
  try { await api(`/api/workers/${w.worker_id}/release`, { method: "POST" }); } catch (e) { alert(e.message); }
}

async function drain(w) {
  if (!confirm(`Drain ${w.name} (${w.worker_id})? It finishes the units it holds, hands back the rest, and exits.`)) return;
  try { await api(`/api/workers/${w.worker_id}/drain`, { method: "POST" }); } catch (e) { alert(e.message); }
  refresh();
}

async function cancel(id) {
  if (!confirm(`Cancel ${id}?`)) return;
  try { await api(`/api/jobs/${id}/cancel`, { method: "POST" }); } catch (e) { alert(e.message); }
  refresh();
}

async function retry(id, frame) {
  const what = frame === undefined ? id : `${id} frame ${frame}`;
  if (!confirm(`Retry ${what}? Its failed frames go back in the queue and render from the start.`)) return;
  const q = frame === undefined ? "" : `?frame=${frame}`;
  try { await api(`/api/jobs/${id}/retry${q}`, { method: "POST" }); } catch (e) { alert(e.message); }
  refresh();
}

async function setPaused(id, paused) {
  try { await api(`/api/jobs/${id}/${paused ? "pause" : "resume"}`, { method: "POST" }); } catch (e) { alert(e.message); }
  refresh();
}

async function setPriority(id, value) {
  const priority = Number(value);
  if (!Number.isInteger(priority)) { alert(`The priority must be a whole number, not ${JSON.stringify(value)}`); return; }
  try {
    await api(`/api/jobs/${id}/priority`, { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify({ priority }) });
  } catch (e) { alert(e.message); }
  refresh();
}

// The job page's controls for a job still to finish: pause or resume, and its priority. The
// priority box is kept across refreshes (it is moved, not rebuilt), so what is being typed
// into it stays.
function liveControls(j) {
  const pause = j.paused
    ? el("button", { id: "resume", onclick: () => setPaused(j.job_id, false) }, "Resume")
    : el("button", { id: "pause", onclick: () => setPaused(j.job_id, true) }, "Pause");
  let box = document.getElementById("priority-input");
  if (!box || box.dataset.job !== j.job_id) {
    box = el("input", { id: "priority-input", type: "number", step: "1", value: String(j.priority), "data-job": j.job_id, "aria-label": "Priority" });
    box.style.width = "5em";
  }
  const set = el("button", { id: "set-priority", onclick: () => setPriority(j.job_id, box.value) }, "Set priority");
  return [pause, box, set];
}

// The job list's and job page's action for a job: Cancel while it runs, Retry once it failed.
function jobAction(j) {
  if (live(j.state)) return el("button", { class: "danger", onclick: () => cancel(j.job_id) }, "Cancel");
  if (j.retryable) return el("button", { class: "retry", onclick: () => retry(j.job_id) }, "Retry");
  return "";
}

// ---- job list

// A finished image's failed checks (black, non-finite samples), as a mark whose title says them.
function flag(checks) {
  if (!checks || checks.length === 0) return "";
  return el("span", { class: "flag", title: checks.map((c) => c.message).join("\n") }, " flagged: " + [...new Set(checks.map((c) => c.code))].join(", "));
}

// ---- submitting a job

// The submit form, built once and moved (not rebuilt) on each refresh, so that what is typed
// into it and the files chosen stay.
let submitForm = null;

// SHA-256 of a file's bytes, as hex (the coordinator stores files by it).
async function sha256(bytes) {
  if (!crypto.subtle) throw new Error("uploading files needs the dashboard over https or on localhost (the browser's hashing is off elsewhere); use tessera submit");
  const d = await crypto.subtle.digest("SHA-256", bytes);
  return Array.from(new Uint8Array(d), (b) => b.toString(16).padStart(2, "0")).join("");
}

// Uploads one chosen file and returns its hash.
async function uploadFile(file) {
  const bytes = await file.arrayBuffer();
  const sha = await sha256(bytes);
  await api(`/api/assets/${sha}?offset=0&total=${bytes.byteLength}`, { method: "PUT", body: bytes });
  return sha;
}

const SCENE_EXT = /\.(toml|json|gltf|glb)$/i;
const MISSING = /`([^`]+)` is not among the files sent with the job/;

// Submits the form's job: the scene (the first chosen file that is a scene: TOML, JSON or
// glTF), then, as the coordinator names each file the scene needs, the chosen file of that
// name, uploaded. Returns the new job's id.
async function submitJob(form, say) {
  const chosen = Array.from(form.querySelector("#submit-files").files);
  const scene = chosen.find((f) => SCENE_EXT.test(f.name));
  if (!scene) throw new Error("choose the scene file (.toml, .json, .gltf or .glb), and the files it names");
  const spp = Number(form.querySelector("#submit-spp").value);
  if (!Number.isInteger(spp) || spp < 1) throw new Error("samples per pixel: a whole number of at least 1");
  const ext = scene.name.split(".").pop().toLowerCase();
  const body = { spp, scene_name: scene.name, files: {} };
  if (ext === "gltf" || ext === "glb") {
    say(`uploading ${scene.name}…`);
    body.format = "gltf";
    body.scene = scene.name;
    body.files[scene.name] = await uploadFile(scene);
  } else {
    body.format = ext;
    body.scene = await scene.text();
  }
  const frames = form.querySelector("#submit-frames").value.trim();
  if (frames) body.frames = frames;
  const name = form.querySelector("#submit-name").value.trim();
  if (name) body.name = name;
  const priority = Number(form.querySelector("#submit-priority").value || "0");
  if (!Number.isInteger(priority)) throw new Error("priority: a whole number");
  body.priority = priority;
  if (form.querySelector("#submit-denoise").checked) {
    body.denoise = { quality: form.querySelector("#submit-quality").value };
  }
  // Each refusal names the next file the scene needs; a scene names at most a few hundred.
  for (let tries = 0; tries < 512; tries++) {
    say("submitting…");
    try {
      return (await api("/api/jobs", { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body) })).job_id;
    } catch (e) {
      const m = MISSING.exec(e.message);
      if (!m) throw e;
      const wanted = m[1];
      const base = wanted.split("/").pop();
      const file = chosen.find((f) => f.name === base);
      if (!file || body.files[wanted]) throw new Error(`${e.message}: choose ${base} too`);
      say(`uploading ${wanted}…`);
      body.files[wanted] = await uploadFile(file);
    }
  }
  throw new Error("the scene names too many files");
}

function submitBox() {
  if (submitForm) return submitForm;
  const note = el("span", { id: "submit-note", class: "muted" });
  const say = (t, bad = false) => { note.textContent = t; note.className = bad ? "error" : "muted"; };
  const quality = el("select", { id: "submit-quality", "aria-label": "Denoise quality" },
    el("option", { value: "fast" }, "fast"), el("option", { value: "balanced" }, "balanced"), el("option", { value: "high", selected: "" }, "high"));
  const go = el("button", { id: "submit-go", type: "submit" }, "Submit");
  const form = el("form", { id: "submit-form" },
    el("label", {}, "Scene and its files ", el("input", { id: "submit-files", type: "file", multiple: "" })),
    el("label", {}, "Samples per pixel ", el("input", { id: "submit-spp", type: "number", min: "1", step: "1", value: "64" })),
    el("label", {}, "Frames ", el("input", { id: "submit-frames", type: "text", placeholder: "1-240:2", size: "9" })),
    el("label", {}, "Output name ", el("input", { id: "submit-name", type: "text", placeholder: "shot.exr", size: "12" })),
    el("label", {}, "Priority ", el("input", { id: "submit-priority", type: "number", step: "1", value: "0" })),
    el("label", {}, el("input", { id: "submit-denoise", type: "checkbox" }), " Denoise"), quality,
    go, note);
  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    go.disabled = true;
    try {
      const id = await submitJob(form, say);
      say(`submitted ${id}`);
      location.href = `/jobs/${id}`;
    } catch (e) {
      say(e.message, true);
    } finally {
      go.disabled = false;
    }
  });
  submitForm = el("details", { id: "submit" }, el("summary", {}, "Submit a job"), form);
  return submitForm;
}

function jobsView(jobs) {
  const rows = jobs.map((j) => el("tr", { "data-job": j.job_id },
    el("td", {}, el("a", { href: `/jobs/${j.job_id}` }, j.job_id)),
    el("td", { class: "scene", title: j.scene }, j.scene),
    el("td", {}, stateTag(j.paused ? "paused" : j.state), flag(j.checks), j.waiting ? el("span", { class: "flag waiting", title: "waiting: " + j.waiting }, " waiting") : ""),
    el("td", {}, bar(j.samples_done, j.samples_total)),
    el("td", { class: "num" }, `${fmt.count(j.samples_done)} / ${fmt.count(j.samples_total)}`),
    el("td", { class: "num" }, fmt.msps(j.samples_per_second)),
    el("td", { class: "num" }, j.samples_done > 0 ? fmt.noise(j.noise_relative) : "–"),
    el("td", { class: "num" }, j.state === "done" ? "done" : fmt.eta(j.eta_seconds)),
    el("td", { class: "num" }, j.priority),
    el("td", {}, jobAction(j)),
  ));
  return [
    el("h1", {}, "Jobs ", el("span", { class: "muted" }, `(${jobs.length})`)),
    submitBox(),
    jobs.length === 0 ? el("p", { class: "muted" }, "No jobs yet: tessera submit SCENE --spp N") :
    el("div", { class: "scroll" }, el("table", { id: "jobs" },
      el("thead", {}, el("tr", {}, ...["Job", "Scene", "State", "Progress", "Samples", "Msamples/s", "Noise", "ETA", "Priority", ""].map((h, i) => el("th", { class: i >= 4 && i <= 8 ? "num" : "" }, h)))),
      el("tbody", {}, ...rows))),
  ];
}

// ---- one job

const preview = { exposure: 0, view: "color", shown: null, loading: false, lastLoad: 0 };

function previewUrl(id, tag) {
  return `/api/jobs/${id}/preview.png?exposure=${preview.exposure}&view=${preview.view}&t=${tag}`;
}

// Loads the next preview off screen and swaps it in once decoded, so the picture never
// flickers; at most one load at a time, and at most one a second.
function updatePreview(j) {
  const img = document.getElementById("preview");
  if (!img || preview.loading) return;
  const tag = `${j.units_done}-${j.state}-${preview.exposure}-${preview.view}`;
  if (tag === preview.shown) return;
  if (live(j.state) && Date.now() - preview.lastLoad < 1000) return;
  if (j.units_done === 0) {
    // Nothing merged: no picture yet, or (a job that ended so) never; no request, no icon.
    img.hidden = true;
    preview.shown = tag;
    document.getElementById("preview-note").textContent =
      live(j.state) ? "no samples merged yet" : `${j.state} before any sample was merged: no picture`;
    return;
  }
  preview.loading = true;
  preview.lastLoad = Date.now();
  const next = new Image();
  next.onload = () => {
    img.src = next.src;
    img.hidden = false;
    img.dataset.units = j.units_done;
    img.dataset.state = j.state;
    img.dataset.view = preview.view;
    img.dataset.exposure = String(preview.exposure);
    preview.shown = tag;
    preview.loading = false;
    document.getElementById("preview-note").textContent =
      preview.view === "noise" ? "relative noise per tile: blue 0.1%, green 3%, red 100%" : "";
  };
  next.onerror = async () => {
    preview.loading = false;
    if (!img.getAttribute("src")) img.hidden = true;
    preview.shown = tag;
    let msg = "no preview";
    try { const r = await fetch(next.src); msg = (await r.json()).error; } catch (_) { /* keep the default */ }
    document.getElementById("preview-note").textContent = msg;
  };
  next.src = previewUrl(j.job_id, tag);
}

function jobView(j) {
  const stats = [
    ["State", stateTag(j.paused ? "paused" : j.state)],
    ["Progress", bar(j.samples_done, j.samples_total)],
    ["Units", `${fmt.count(j.units_done)} / ${fmt.count(j.units_total)} (${j.units_leased} leased)`],
    ["Samples", `${fmt.count(j.samples_done)} / ${fmt.count(j.samples_total)}`],
    ["Msamples/s", fmt.msps(j.samples_per_second)],
    ["Noise", j.samples_done > 0 ? `${fmt.noise(j.noise_relative)} (rms ${j.noise_rms.toPrecision(3)})` : "–"],
    ["ETA", j.state === "done" ? "done" : fmt.eta(j.eta_seconds)],
    ["Image", `${j.width}×${j.height}, ${j.spp} spp, seed ${j.seed}`],
    ["Priority", j.priority],
    ["Output", j.output],
  ];
  if (j.submitter) stats.push(["Submitter", j.submitter]);
  if (j.after) stats.push(["After", el("span", {}, el("a", { href: `/jobs/${j.after}` }, j.after), j.state === "queued" ? " (starts when it is done)" : "")]);
  if (j.require.length > 0 || j.min_memory_bytes > 0) stats.push(["Requires", [...j.require, ...(j.min_memory_bytes > 0 ? [fmt.gib(j.min_memory_bytes) + " of memory"] : [])].join(", ")]);
  if (j.waiting) stats.push(["Waiting", el("span", { class: "flag" }, j.waiting)]);
  if (j.error) stats.push(["Error", el("span", { class: "error" }, j.error)]);
  if (j.retries > 0) stats.push(["Retried", `${j.retries} time(s)`]);
  if (j.checks.length > 0) stats.push(["Checks", el("ul", { class: "checks", id: "checks" }, ...j.checks.map((c) => el("li", { class: "flag", "data-code": c.code }, c.message)))]);
  const side = [el("dl", { class: "stats", id: "stats" }, ...stats.flatMap(([k, v]) => [el("dt", {}, k), el("dd", { id: "stat-" + k.toLowerCase().replace(/\W/g, "") }, v)]))];
  const actions = el("p", { class: "controls" });
  if (live(j.state)) actions.append(...liveControls(j));
  actions.append(jobAction(j));
  if (j.state === "done" && j.frames.length === 0) actions.append(el("a", { id: "download", href: `/api/jobs/${j.job_id}/output.exr`, download: j.output }, "Download EXR"));
  side.push(actions);
  side.push(el("div", { id: "logs" }, el("h2", {}, "Worker log"), el("pre", { id: "log-lines", class: "log" }, "…")));
  loadLogs(j.job_id);
  if (j.frames.length > 0) {
    side.push(el("table", { id: "frames" },
      el("thead", {}, el("tr", {}, el("th", {}, "Frame"), el("th", {}, "State"), el("th", {}, "Units"), el("th", {}, ""))),
      el("tbody", {}, ...j.frames.map((f) => el("tr", {},
        el("td", {}, el("a", { href: `/jobs/${f.job_id}` }, f.frame)),
        el("td", {}, stateTag(f.state), flag(f.checks)),
        el("td", { class: "num" }, `${f.units_done}/${f.units_total}`),
        el("td", {}, f.state === "done" ? el("a", { href: `/api/jobs/${j.job_id}/output.exr?frame=${f.frame}`, download: f.output }, "EXR")
          : f.state === "failed" && j.retryable ? el("button", { class: "retry", onclick: () => retry(j.job_id, f.frame) }, "Retry") : ""))))));
    return [el("h1", {}, `${j.job_id} `, el("span", { class: "muted" }, `${j.scene}, ${j.frames.length} frames`)), el("div", { class: "job" }, el("div", {}, el("p", { class: "muted" }, "A frame range: open a frame for its preview.")), el("div", {}, ...side))];
  }
  let img = document.getElementById("preview");
  let box;
  if (img && img.dataset.job === j.job_id) {
    box = img.closest(".preview-col");
  } else {
    img = el("img", { id: "preview", alt: "preview", "data-job": j.job_id, width: j.width, height: j.height });
    // Shown once a picture has loaded: an image with nothing to show would be a broken icon.
    img.hidden = true;
    // Small frames are shown up to twice their size, pixels kept sharp.
    img.style.width = `min(100%, ${2 * j.width}px)`;
    img.style.height = "auto";
    const expo = el("input", { id: "exposure", type: "range", min: "-6", max: "6", step: "0.5", value: String(preview.exposure) });
    const expoLabel = el("span", { id: "exposure-value" }, `${preview.exposure} EV`);
    expo.addEventListener("input", () => { preview.exposure = Number(expo.value); expoLabel.textContent = `${preview.exposure} EV`; preview.lastLoad = 0; refresh(); });
    const toggle = el("button", { id: "view-toggle" }, preview.view === "noise" ? "Show image" : "Show noise");
    // A job submitted with --denoise also has its denoised image: while it runs, its preview
    // filtered by the coordinator (where it has the library); once done, the EXR's layer. Any
    // other job answers this view with a note saying why not.
    const denoised = el("button", { id: "denoised-toggle" }, preview.view === "denoised" ? "Show image" : "Show denoised");
    const relabel = () => {
      toggle.textContent = preview.view === "noise" ? "Show image" : "Show noise";
      denoised.textContent = preview.view === "denoised" ? "Show image" : "Show denoised";
    };
    toggle.addEventListener("click", () => { preview.view = preview.view === "noise" ? "color" : "noise"; relabel(); preview.lastLoad = 0; refresh(); });
    denoised.addEventListener("click", () => { preview.view = preview.view === "denoised" ? "color" : "denoised"; relabel(); preview.lastLoad = 0; refresh(); });
    box = el("div", { class: "preview-col" },
      el("div", { class: "preview" }, img),
      el("div", { class: "controls" }, el("label", { for: "exposure" }, "Exposure"), expo, expoLabel, toggle, denoised, el("span", { id: "preview-note", class: "muted" }, "")));
  }
  return [el("h1", {}, `${j.job_id} `, el("span", { class: "muted" }, j.scene)), el("div", { class: "job" }, box, el("div", {}, ...side))];
}

// The job's worker log (warnings and errors about its units), loaded with each refresh.
async function loadLogs(id) {
  try {
    const r = await api(`/api/jobs/${id}/logs`);
    const pre = document.getElementById("log-lines");
    if (!pre) return;
    const lines = r.entries.map((e) => `${new Date(e.unix_ms).toISOString()} ${e.job_id}${e.frame != null ? " frame " + e.frame : ""} tile ${e.tile} batch ${e.batch} ${e.worker_id} (${e.worker_name}): ${e.level}: ${e.message}`);
    if (r.dropped > 0) lines.unshift(`(${r.dropped} lines not kept)`);
    pre.textContent = lines.length > 0 ? lines.join("\n") : "No warnings or errors from workers.";
  } catch (_) { /* the next refresh tries again */ }
}

// ---- workers

function workersView(ws) {
  const rows = ws.map((w) => el("tr", {},
    el("td", { class: "name", title: w.name }, w.name, el("div", { class: "muted" }, w.worker_id)),
    el("td", {}, w.host || "–"),
    el("td", { class: "num" }, w.cores),
    el("td", { class: "num" }, w.memory_bytes > 0 ? fmt.gib(w.memory_bytes) : "–"),
    el("td", { class: "tags", title: w.tags.join(" ") }, w.tags.join(" ") || "–"),
    el("td", {}, stateTag(w.state), w.convicted ? el("div", { class: "error" }, w.convicted) : ""),
    el("td", { class: "num" }, w.leases),
    el("td", { class: "num" }, fmt.count(w.units_done)),
    el("td", { class: "num" }, fmt.msps(w.samples_per_second)),
    el("td", { class: "num" }, w.bad_results),
    el("td", { class: "num" }, w.audits_passed),
    el("td", {}, fmt.ago(1000 * w.last_seen_seconds_ago)),
    el("td", {}, w.state === "alive" || w.state === "suspect" ? el("button", { onclick: () => drain(w) }, "Drain") :
      w.state === "quarantined" || w.state === "convicted" ? el("button", { onclick: () => release(w) }, "Release") : ""),
  ));
  return [
    el("h1", {}, "Workers ", el("span", { class: "muted" }, `(${ws.filter((w) => w.state === "alive").length} alive)`)),
    ws.length === 0 ? el("p", { class: "muted" }, "No workers yet: tessera worker --coordinator URL") :
    el("div", { class: "scroll" }, el("table", { id: "workers" },
      el("thead", {}, el("tr", {}, ...["Worker", "Host", "Threads", "Memory", "Tags", "State", "Leases", "Units done", "Msamples/s", "Bad results", "Audits passed", "Last heartbeat", ""].map((h, i) => el("th", { class: [2, 3, 6, 7, 8, 9, 10].includes(i) ? "num" : "" }, h)))),
      el("tbody", {}, ...rows))),
  ];
}

// ---- routing and polling

async function refresh() {
  const path = location.pathname;
  try {
    let nodes;
    let job = null;
    if (path === "/workers") {
      nodes = workersView(await api("/api/workers"));
    } else if (path.startsWith("/jobs/")) {
      job = await api(`/api/jobs/${encodeURIComponent(path.slice(6))}`);
      nodes = jobView(job);
    } else {
      nodes = jobsView(await api("/api/jobs"));
    }
    main.replaceChildren(...nodes);
    if (job && job.frames.length === 0) updatePreview(job);
  } catch (e) {
    main.replaceChildren(el("p", { class: "error", id: "error" }, e.message));
  }
}

document.getElementById(location.pathname === "/workers" ? "nav-workers" : "nav-jobs").classList.add("active");
refresh();
setInterval(refresh, POLL_MS);
