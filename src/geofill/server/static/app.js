// geofill page: plain JavaScript (no build step, no library), talking only to /api/v1.
// The editor shows one photo at a time: the target, whose mask is the hole, or a reference, whose
// mask is what must never be copied from it. Each photo's mask is a full-resolution canvas rebuilt
// from its own operation list (strokes, clear, uploaded mask), which is what makes undo/redo cheap;
// the photo is shown scaled and panned.
"use strict";

const $ = (id) => document.getElementById(id);
const HOLE_RGB = "rgb(255, 0, 160)"; // the target's hole
// A reference's mask: never copied into the hole. Sent as the mask canvas's PNG, read by its alpha;
// a reference masked all over has a uniform alpha and is read by luminance, which is 141 >= 127 here.
const KEEP_OUT_RGB = "rgb(0, 190, 255)";
const MASK_OPACITY = 0.45;
const POLL_MS = 300;
const THUMB_SIDE = 184; // px: long side of a reference's mask thumbnail

const state = {
  target: null, // {blob, name, layer}
  refs: [], // {file, url, layer, thumb}
  doc: null, // the layer open in the editor: the target's or a reference's
  refsVersion: 0, // counts changes to the references and their masks (a new fill is worth it)
  stroke: null,
  tool: "brush",
  spaceDown: false,
  pan: null, // {x, y, ox, oy} while dragging the view
  view: { scale: 1, ox: 0, oy: 0 },
  pointer: null, // last pointer position in canvas px
  job: null, // {id, timer, refsVersion}
  result: null, // {bitmap, coverage, data, refsVersion}
  fields: [],
};

const view = $("view");
const ctx = view.getContext("2d");

// A photo with its mask: ops is the undo stack ({type: "stroke", erase, size, points} |
// {type: "clear"} | {type: "mask", canvas}), view its zoom and pan when another photo is open.
function newLayer(bitmap, colour) {
  const mask = document.createElement("canvas");
  mask.width = bitmap.width;
  mask.height = bitmap.height;
  return { bitmap, colour, mask, mctx: mask.getContext("2d"), ops: [], redo: [], view: null };
}

const isTarget = (layer) => Boolean(state.target) && layer === state.target.layer;
const refOf = (layer) => state.refs.findIndex((r) => r.layer === layer);

// ---------------------------------------------------------------- messages

function say(text) {
  $("message").textContent = text || "";
}

async function errorText(resp) {
  try {
    const body = await resp.json();
    return typeof body.detail === "string" ? body.detail : JSON.stringify(body.detail);
  } catch (e) {
    return `${resp.status} ${resp.statusText}`;
  }
}

// ---------------------------------------------------------------- loading photos

async function decode(blob) {
  try {
    return await createImageBitmap(blob, { imageOrientation: "from-image" });
  } catch (e) {
    throw new Error(`${blob.name || "this file"}: this browser cannot show it (PNG, JPEG or WebP work everywhere)`);
  }
}

async function setTarget(blob, name) {
  const bitmap = await decode(blob);
  state.target = { blob, name, layer: newLayer(bitmap, HOLE_RGB) };
  state.result = null;
  $("drop-target").hidden = true;
  view.hidden = false;
  $("result").hidden = true;
  openLayer(state.target.layer);
}

// Show ``layer`` (the target's or a reference's) in the editor, zoomed and panned as the user left it.
function openLayer(layer) {
  const i = refOf(layer);
  $("editing").hidden = i < 0;
  if (i >= 0) {
    $("editing-text").textContent = `Reference ${i + 1} (${state.refs[i].file.name}): brush what must never be copied from it, such as a passer-by or a parked car.`;
  }
  $("tools-title").textContent = i < 0 ? "1. Mark the hole" : `Mark what not to copy from reference ${i + 1}`;
  $("compare").hidden = i >= 0 || !state.result;
  resize(); // the bars above the photo may have come or gone
  if (layer !== state.doc) {
    if (state.doc) state.doc.view = { ...state.view };
    state.doc = layer;
    state.stroke = null;
    if (layer.view) state.view = { ...layer.view };
    else fit();
  }
  rebuildMask();
  renderRefs();
  update();
}

async function addRefs(files) {
  for (const file of files) {
    let bitmap;
    try {
      bitmap = await decode(file); // refuse now what the browser cannot show as a thumbnail
    } catch (e) {
      say(e.message);
      continue;
    }
    const thumb = document.createElement("canvas");
    const s = Math.min(1, THUMB_SIDE / Math.max(bitmap.width, bitmap.height));
    thumb.width = Math.max(1, Math.round(bitmap.width * s));
    thumb.height = Math.max(1, Math.round(bitmap.height * s));
    state.refs.push({ file, url: URL.createObjectURL(file), layer: newLayer(bitmap, KEEP_OUT_RGB), thumb });
    state.refsVersion++;
  }
  renderRefs();
  update();
}

function removeRef(i) {
  const [ref] = state.refs.splice(i, 1);
  URL.revokeObjectURL(ref.url);
  state.refsVersion++;
  if (state.target) openLayer(state.doc === ref.layer ? state.target.layer : state.doc); // renumbered
  else {
    renderRefs();
    update();
  }
}

function renderRefs() {
  const list = $("ref-list");
  list.replaceChildren();
  state.refs.forEach((ref, i) => {
    const masked = !maskIsEmpty(ref.layer);
    const editing = state.doc === ref.layer;
    const li = document.createElement("li");
    li.classList.toggle("masked", masked);
    const opener = document.createElement("button");
    opener.type = "button";
    opener.className = "thumb";
    opener.setAttribute("aria-pressed", String(editing));
    opener.title = editing
      ? `Reference ${i + 1} is open: brush what must not be copied from it`
      : `Open reference ${i + 1} to mark what must not be copied from it`;
    opener.addEventListener("click", () => {
      if (!state.target) return say("Open the photo first; then a reference opens here to mark what not to copy.");
      openLayer(editing ? state.target.layer : ref.layer);
    });
    const img = document.createElement("img");
    img.src = ref.url;
    img.alt = `reference ${i + 1}: ${ref.file.name}`;
    drawThumb(ref);
    opener.append(img, ref.thumb);
    const label = document.createElement("span");
    label.textContent = masked ? `reference ${i + 1} · masked` : `reference ${i + 1}`;
    const remove = document.createElement("button");
    remove.type = "button";
    remove.className = "remove";
    remove.textContent = "×";
    remove.title = `Remove reference ${i + 1}`;
    remove.setAttribute("aria-label", `Remove reference ${i + 1}`);
    remove.addEventListener("click", () => removeRef(i));
    li.append(opener, label, remove);
    list.append(li);
  });
  $("refs-hint").hidden = !state.refs.length;
}

// The reference's mask, small, over its thumbnail.
function drawThumb(ref) {
  const c = ref.thumb.getContext("2d");
  c.clearRect(0, 0, ref.thumb.width, ref.thumb.height);
  c.drawImage(ref.layer.mask, 0, 0, ref.thumb.width, ref.thumb.height);
}

async function useMaskFile(file) {
  if (!state.doc) return say("Open the photo first.");
  const bitmap = await decode(file);
  const { width, height } = state.doc.bitmap;
  const what = isTarget(state.doc) ? "the photo" : `reference ${refOf(state.doc) + 1}`;
  if (bitmap.width !== width || bitmap.height !== height) {
    return say(`The mask is ${bitmap.width}×${bitmap.height}; ${what} is ${width}×${height}.`);
  }
  // The CLI's rule: alpha when the mask has transparency, else luminance; >= 127 is hole.
  const c = document.createElement("canvas");
  c.width = width;
  c.height = height;
  const cc = c.getContext("2d");
  cc.drawImage(bitmap, 0, 0);
  const px = cc.getImageData(0, 0, width, height);
  const d = px.data;
  let transparent = false;
  for (let i = 3; i < d.length; i += 4) if (d[i] < 255) { transparent = true; break; }
  const [r, g, b] = state.doc.colour.match(/\d+/g).map(Number);
  for (let i = 0; i < d.length; i += 4) {
    const v = transparent ? d[i + 3] : 0.299 * d[i] + 0.587 * d[i + 1] + 0.114 * d[i + 2];
    const hole = v >= 127;
    d[i] = r; d[i + 1] = g; d[i + 2] = b; d[i + 3] = hole ? 255 : 0;
  }
  cc.putImageData(px, 0, 0);
  pushOp({ type: "mask", canvas: c });
}

function wireDrop(zone, onFiles) {
  zone.addEventListener("dragover", (e) => { e.preventDefault(); zone.classList.add("over"); });
  zone.addEventListener("dragleave", () => zone.classList.remove("over"));
  zone.addEventListener("drop", (e) => {
    e.preventDefault();
    zone.classList.remove("over");
    if (e.dataTransfer.files.length) onFiles([...e.dataTransfer.files]);
  });
}

// ---------------------------------------------------------------- the mask (operation list)

function drawOp(op, layer = state.doc) {
  const { mask, mctx } = layer;
  if (op.type === "clear") {
    mctx.clearRect(0, 0, mask.width, mask.height);
  } else if (op.type === "mask") {
    mctx.globalCompositeOperation = "source-over";
    mctx.clearRect(0, 0, mask.width, mask.height);
    mctx.drawImage(op.canvas, 0, 0);
  } else {
    mctx.globalCompositeOperation = op.erase ? "destination-out" : "source-over";
    mctx.strokeStyle = mctx.fillStyle = layer.colour;
    mctx.lineWidth = op.size;
    mctx.lineCap = mctx.lineJoin = "round";
    const p = op.points;
    if (p.length === 1) {
      mctx.beginPath();
      mctx.arc(p[0][0], p[0][1], op.size / 2, 0, 2 * Math.PI);
      mctx.fill();
    } else {
      mctx.beginPath();
      mctx.moveTo(p[0][0], p[0][1]);
      for (let i = 1; i < p.length; i++) mctx.lineTo(p[i][0], p[i][1]);
      mctx.stroke();
    }
    mctx.globalCompositeOperation = "source-over";
  }
}

function rebuildMask() {
  const layer = state.doc;
  layer.mctx.clearRect(0, 0, layer.mask.width, layer.mask.height);
  layer.ops.forEach((op) => drawOp(op, layer));
  render();
}

// After the open layer's operation list changed: redraw, and a reference's thumbnail too.
function masksChanged() {
  rebuildMask();
  if (!isTarget(state.doc)) {
    state.refsVersion++;
    renderRefs();
  }
  update();
}

function pushOp(op) {
  state.doc.ops.push(op);
  state.doc.redo = [];
  masksChanged();
}

function undo() {
  if (!state.doc.ops.length) return;
  state.doc.redo.push(state.doc.ops.pop());
  masksChanged();
}

function redo() {
  if (!state.doc.redo.length) return;
  state.doc.ops.push(state.doc.redo.pop());
  masksChanged();
}

function maskIsEmpty(layer = state.doc) {
  return !layer.ops.length || layer.ops[layer.ops.length - 1].type === "clear";
}

// Whether the open photo shows a fill's result (strokes then pan it: the hole cannot change).
const showingResult = () => Boolean(state.result) && isTarget(state.doc);

// ---------------------------------------------------------------- view: zoom, pan, render

function resize() {
  const dpr = window.devicePixelRatio || 1;
  view.width = Math.max(1, Math.round(view.clientWidth * dpr));
  view.height = Math.max(1, Math.round(view.clientHeight * dpr));
  render();
}

function fit() {
  if (!state.doc) return;
  const { width, height } = state.doc.bitmap;
  const s = Math.min(view.width / width, view.height / height);
  state.view = { scale: s, ox: (view.width - width * s) / 2, oy: (view.height - height * s) / 2 };
  render();
}

function zoomAt(factor, cx = view.width / 2, cy = view.height / 2) {
  const v = state.view;
  const s = Math.min(Math.max(v.scale * factor, 0.02), 32);
  v.ox = cx - ((cx - v.ox) * s) / v.scale;
  v.oy = cy - ((cy - v.oy) * s) / v.scale;
  v.scale = s;
  render();
}

function panBy(dx, dy) {
  state.view.ox += dx;
  state.view.oy += dy;
  render();
}

function toImage(x, y) {
  const v = state.view;
  return [(x - v.ox) / v.scale, (y - v.oy) / v.scale];
}

function canvasPoint(e) {
  const r = view.getBoundingClientRect();
  return [((e.clientX - r.left) * view.width) / r.width, ((e.clientY - r.top) * view.height) / r.height];
}

function render() {
  ctx.setTransform(1, 0, 0, 1, 0, 0);
  ctx.clearRect(0, 0, view.width, view.height);
  if (!state.doc) return;
  const v = state.view;
  const { width, height } = state.doc.bitmap;
  ctx.setTransform(v.scale, 0, 0, v.scale, v.ox, v.oy);
  ctx.imageSmoothingEnabled = v.scale < 2;
  ctx.drawImage(state.doc.bitmap, 0, 0);
  if (showingResult()) {
    const split = (Number($("split").value) / 100) * width;
    ctx.save();
    ctx.beginPath();
    ctx.rect(0, 0, split, height);
    ctx.clip();
    ctx.drawImage(state.result.bitmap, 0, 0);
    if ($("show-coverage").checked) ctx.drawImage(state.result.coverage, 0, 0);
    ctx.restore();
    ctx.fillStyle = "#fff";
    ctx.fillRect(split - 1 / v.scale, 0, 2 / v.scale, height);
  } else {
    ctx.globalAlpha = MASK_OPACITY;
    ctx.drawImage(state.doc.mask, 0, 0);
    ctx.globalAlpha = 1;
  }
  ctx.setTransform(1, 0, 0, 1, 0, 0);
  if (state.pointer && !showingResult() && state.tool !== "pan" && !state.spaceDown) {
    ctx.strokeStyle = "#fff";
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    ctx.arc(state.pointer[0], state.pointer[1], brushSize() / 2, 0, 2 * Math.PI);
    ctx.stroke();
  }
  $("zoom-value").textContent = `${Math.round(v.scale * 100)} %`;
}

function brushSize() {
  return Number($("brush-size").value) * (window.devicePixelRatio || 1);
}

// ---------------------------------------------------------------- pointer and keyboard

function setTool(tool) {
  state.tool = tool;
  for (const t of ["brush", "eraser", "pan"]) $(`tool-${t}`).setAttribute("aria-pressed", String(t === tool));
  view.classList.toggle("panning", tool === "pan");
  render();
}

view.addEventListener("pointerdown", (e) => {
  if (!state.doc) return;
  view.focus();
  view.setPointerCapture(e.pointerId);
  const [x, y] = canvasPoint(e);
  const panning = e.button === 1 || state.tool === "pan" || state.spaceDown || showingResult();
  if (panning) {
    state.pan = { x, y, ox: state.view.ox, oy: state.view.oy };
    return;
  }
  if (e.button !== 0) return;
  const size = brushSize() / state.view.scale;
  state.stroke = { type: "stroke", erase: state.tool === "eraser", size, points: [toImage(x, y)] };
  drawOp(state.stroke);
  render();
});

view.addEventListener("pointermove", (e) => {
  const [x, y] = canvasPoint(e);
  state.pointer = [x, y];
  if (state.pan) {
    state.view.ox = state.pan.ox + x - state.pan.x;
    state.view.oy = state.pan.oy + y - state.pan.y;
  } else if (state.stroke) {
    state.stroke.points.push(toImage(x, y));
    const p = state.stroke.points;
    drawOp({ ...state.stroke, points: p.slice(-2) }); // only the new segment; replay draws it whole
  }
  render();
});

function endPointer() {
  if (state.stroke) {
    const stroke = state.stroke;
    state.stroke = null;
    pushOp(stroke);
  }
  state.pan = null;
}
view.addEventListener("pointerup", endPointer);
view.addEventListener("pointercancel", endPointer);
view.addEventListener("pointerleave", () => { state.pointer = null; render(); });
view.addEventListener("wheel", (e) => {
  e.preventDefault();
  const [x, y] = canvasPoint(e);
  zoomAt(Math.exp(-e.deltaY * 0.0015), x, y);
}, { passive: false });

document.addEventListener("keydown", (e) => {
  const typing = ["INPUT", "SELECT", "TEXTAREA"].includes(e.target.tagName) && e.target.type !== "range";
  if (typing || !state.doc) return;
  const mod = e.ctrlKey || e.metaKey;
  const key = e.key.toLowerCase();
  let handled = true;
  if (mod && key === "z" && !e.shiftKey) undo();
  else if (mod && (key === "y" || (key === "z" && e.shiftKey))) redo();
  else if (mod) handled = false;
  else if (key === "b") setTool("brush");
  else if (key === "e") setTool("eraser");
  else if (key === "h") setTool("pan");
  else if (key === "[") stepSize(-1);
  else if (key === "]") stepSize(1);
  else if (key === "+" || key === "=") zoomAt(1.25);
  else if (key === "-") zoomAt(0.8);
  else if (key === "0") fit();
  else if (key === "escape" && !isTarget(state.doc)) openLayer(state.target.layer);
  else if (e.target === view && key.startsWith("arrow")) {
    const d = 60;
    panBy(key === "arrowleft" ? d : key === "arrowright" ? -d : 0, key === "arrowup" ? d : key === "arrowdown" ? -d : 0);
  } else if (key === " " && e.target === view) {
    state.spaceDown = true;
    view.classList.add("panning");
  } else handled = false;
  if (handled) e.preventDefault();
});
document.addEventListener("keyup", (e) => {
  if (e.key === " ") {
    state.spaceDown = false;
    view.classList.toggle("panning", state.tool === "pan");
  }
});

function stepSize(direction) {
  const input = $("brush-size");
  const v = Number(input.value);
  input.value = Math.round(Math.min(Math.max(v * (direction > 0 ? 1.25 : 0.8), 2), 300));
  $("brush-size-value").textContent = input.value;
  render();
}

// ---------------------------------------------------------------- advanced options (from the schema)

async function loadFields() {
  const resp = await fetch("/api/v1/config/fields");
  if (!resp.ok) return;
  const { fields } = await resp.json();
  state.fields = fields.filter((f) => !f.locked);
  const box = $("advanced-fields");
  const sets = new Map();
  for (const f of state.fields) {
    const section = f.section || "general";
    if (!sets.has(section)) {
      const fs = document.createElement("fieldset");
      const legend = document.createElement("legend");
      legend.textContent = section;
      fs.append(legend);
      sets.set(section, fs);
      box.append(fs);
    }
    const label = document.createElement("label");
    label.title = f.description;
    const name = document.createElement("span");
    name.textContent = f.key.split(".").pop();
    let input;
    if (f.kind === "choice") {
      input = document.createElement("select");
      for (const c of f.choices) input.append(new Option(String(c), JSON.stringify(c)));
      input.value = JSON.stringify(f.default);
    } else if (f.kind === "bool") {
      input = document.createElement("input");
      input.type = "checkbox";
      input.checked = f.default;
    } else {
      input = document.createElement("input");
      const numeric = (f.kind === "int" || f.kind === "float") && !f.optional;
      input.type = numeric ? "number" : "text";
      if (numeric) input.step = f.kind === "int" ? "1" : "any";
      input.value = f.default === null ? "" : f.kind === "list" ? JSON.stringify(f.default) : String(f.default);
      if (f.optional) input.placeholder = "default";
    }
    input.dataset.key = f.key;
    input.setAttribute("aria-description", f.description);
    input.addEventListener("change", () => label.classList.toggle("changed", fieldValue(f, input).changed));
    label.append(name, input);
    sets.get(f.section || "general").append(label);
    f.input = input;
  }
}

function fieldValue(f, input) {
  let value;
  if (f.kind === "bool") value = input.checked;
  else if (f.kind === "choice") value = JSON.parse(input.value);
  else if (input.value.trim() === "" && f.optional) value = null;
  else if (f.kind === "int" || f.kind === "float") value = Number(input.value);
  else if (f.kind === "list") {
    try { value = JSON.parse(input.value); } catch (e) { value = input.value; } // the server names the bad key
  } else value = input.value;
  if (f.kind === "int" || f.kind === "float") {
    if (Number.isNaN(value)) value = input.value; // sent as typed: the server's 422 names the key
  }
  return { value, changed: JSON.stringify(value) !== JSON.stringify(f.default) };
}

function configOverrides() {
  const out = {};
  for (const f of state.fields) {
    const { value, changed } = fieldValue(f, f.input);
    if (changed) out[f.key] = value;
  }
  return out;
}

// ---------------------------------------------------------------- fill, progress, result

function update() {
  const busy = Boolean(state.job);
  // After a fill, filling again is worth it once the references or their masks changed.
  const filled = Boolean(state.result) && state.result.refsVersion === state.refsVersion;
  $("fill").disabled =
    busy || !state.target || !state.refs.length || maskIsEmpty(state.target.layer) || filled;
  $("fill").textContent = state.result && !filled ? "Fill again" : "Fill";
  $("cancel").hidden = !busy;
  const doc = state.doc;
  $("undo").disabled = !doc || !doc.ops.length || showingResult();
  $("redo").disabled = !doc || !doc.redo.length || showingResult();
}

const pngOf = (canvas) => new Promise((resolve) => canvas.toBlob(resolve, "image/png"));

async function startFill() {
  say("");
  const form = new FormData();
  form.append("target", state.target.blob, "target");
  form.append("mask", await pngOf(state.target.layer.mask), "mask.png");
  state.refs.forEach((r) => form.append("sources", r.file, r.file.name));
  // source_mask_k: what must never be copied from the k-th reference (alpha >= 127)
  for (const [i, r] of state.refs.entries()) {
    if (!maskIsEmpty(r.layer)) form.append(`source_mask_${i + 1}`, await pngOf(r.layer.mask), `reference-${i + 1}-mask.png`);
  }
  const overrides = configOverrides();
  if (Object.keys(overrides).length) form.append("config", JSON.stringify(overrides));
  $("progress").hidden = false;
  $("progress-bar").value = 0;
  $("stage-text").textContent = "Uploading…";
  state.job = { id: null, timer: null, refsVersion: state.refsVersion };
  update();
  let resp;
  try {
    resp = await fetch("/api/v1/fill", { method: "POST", body: form });
  } catch (e) {
    return endJob(`The server could not be reached: ${e.message}`);
  }
  if (resp.status !== 202) {
    const text = await errorText(resp);
    const wait = resp.headers.get("Retry-After");
    return endJob(wait ? `${text} (about ${wait} s)` : text);
  }
  state.job.id = (await resp.json()).id;
  poll();
}

async function poll() {
  if (!state.job || !state.job.id) return;
  const resp = await fetch(`/api/v1/jobs/${state.job.id}`);
  if (!state.job) return; // cancelled meanwhile
  if (!resp.ok) return endJob(await errorText(resp));
  const job = await resp.json();
  $("progress-bar").value = job.progress;
  if (job.state === "queued") $("stage-text").textContent = "Waiting for a free worker…";
  else if (job.state === "running") $("stage-text").textContent = `${job.stage_text || "Starting"}…`;
  if (job.state === "done") return showResult(job);
  if (job.state === "failed") return endJob(`The fill failed: ${job.error}`);
  if (job.state === "cancelled") return endJob("Cancelled.");
  state.job.timer = setTimeout(poll, POLL_MS);
}

function endJob(message) {
  if (state.job && state.job.timer) clearTimeout(state.job.timer);
  state.job = null;
  $("progress").hidden = true;
  say(message);
  update();
}

async function cancelFill() {
  const job = state.job;
  if (!job) return;
  if (job.timer) clearTimeout(job.timer);
  state.job = null;
  if (job.id) await fetch(`/api/v1/jobs/${job.id}`, { method: "DELETE" });
  endJob("Cancelled.");
}

async function fetchBitmap(url) {
  const resp = await fetch(url);
  if (!resp.ok) throw new Error(await errorText(resp));
  const blob = await resp.blob();
  return { blob, bitmap: await createImageBitmap(blob) };
}

async function showResult(job) {
  const { id, refsVersion } = state.job;
  let result, coverage;
  try {
    result = await fetchBitmap(`/api/v1/jobs/${id}/result`);
    coverage = await fetchBitmap(`/api/v1/jobs/${id}/coverage`);
  } catch (e) {
    return endJob(`The result could not be loaded: ${e.message}`);
  }
  state.result = { bitmap: result.bitmap, blob: result.blob, coverage: coverage.bitmap, data: job, refsVersion };
  endJob("");
  $("summary").textContent = `Hole filled: ${job.summary}.`;
  const legend = $("legend");
  legend.replaceChildren();
  for (const row of job.coverage) {
    const li = document.createElement("li");
    li.style.setProperty("--swatch", row.colour);
    li.textContent = `${row.label}: ${(100 * row.fraction).toFixed(1)} %`;
    legend.append(li);
  }
  const warning = $("warning");
  warning.hidden = job.status !== "single_image";
  warning.textContent = warning.hidden
    ? ""
    : `The reference photos could not help, so the whole hole was painted by single-image inpainting. Why: ${job.fallbacks.join("; ")}`;
  const notes = [...(job.notices || [])];
  if (job.status !== "single_image") notes.push(...job.fallbacks);
  $("notices").textContent = notes.join(" ");
  $("download").href = `/api/v1/jobs/${id}/result`;
  $("result").hidden = false;
  $("compare").hidden = !isTarget(state.doc);
  resize();
  $("split").value = 50;
  update();
  render();
  $("result").scrollIntoView({ block: "nearest" });
}

async function keepEditing() {
  if (state.result) await setTarget(state.result.blob, "result.png"); // references are kept
}

// ---------------------------------------------------------------- wiring

function pick(inputId, handler) {
  const input = $(inputId);
  input.addEventListener("change", () => {
    if (input.files.length) handler([...input.files]).catch((e) => say(e.message));
    input.value = "";
  });
  return () => input.click();
}

const openTarget = pick("file-target", (files) => setTarget(files[0], files[0].name));
$("pick-target").addEventListener("click", openTarget);
$("pick-mask").addEventListener("click", pick("file-mask", (files) => useMaskFile(files[0])));
$("pick-refs").addEventListener("click", pick("file-refs", addRefs));
wireDrop($("drop-target"), (files) => setTarget(files[0], files[0].name).catch((e) => say(e.message)));
wireDrop($("drop-refs"), (files) => addRefs(files));
$("tool-brush").addEventListener("click", () => setTool("brush"));
$("tool-eraser").addEventListener("click", () => setTool("eraser"));
$("tool-pan").addEventListener("click", () => setTool("pan"));
$("brush-size").addEventListener("input", () => { $("brush-size-value").textContent = $("brush-size").value; });
$("undo").addEventListener("click", undo);
$("redo").addEventListener("click", redo);
$("clear").addEventListener("click", () => { if (state.doc && !maskIsEmpty()) pushOp({ type: "clear" }); });
$("back-to-photo").addEventListener("click", () => openLayer(state.target.layer));
$("zoom-in").addEventListener("click", () => zoomAt(1.25));
$("zoom-out").addEventListener("click", () => zoomAt(0.8));
$("zoom-fit").addEventListener("click", fit);
$("fill").addEventListener("click", () => startFill().catch((e) => endJob(e.message)));
$("cancel").addEventListener("click", cancelFill);
$("split").addEventListener("input", render);
$("show-coverage").addEventListener("change", render);
$("keep-editing").addEventListener("click", () => keepEditing().catch((e) => say(e.message)));
window.addEventListener("resize", () => { if (state.doc) { resize(); fit(); } });
loadFields();
update();
