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
  view: { scale: 1, ox: 0, oy: 0, fitted: true }, // fitted: re-fit when the editor's size changes
  pointer: null, // last pointer position in canvas px
  job: null, // {id, timer, refsVersion}
  result: null, // {bitmap, coverage, data, refsVersion}
  fields: [], // the config's options, each with its input and row
  sections: [], // {details, count, members}: the options' groups
};

const view = $("view");
const ctx = view.getContext("2d");
const canvasBox = $("canvas-box");

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
  say(""); // an earlier file's error no longer applies
  state.target = { blob, name, layer: newLayer(bitmap, HOLE_RGB) };
  state.result = null;
  $("drop-target").hidden = true;
  canvasBox.hidden = false;
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
  // On one column the editor takes the photo's shape (style.css).
  canvasBox.style.setProperty("--photo-aspect", `${layer.bitmap.width} / ${layer.bitmap.height}`);
  if (layer !== state.doc) {
    if (state.doc) state.doc.view = { ...state.view };
    state.doc = layer;
    state.stroke = null;
    state.view = layer.view ? { ...layer.view } : { scale: 1, ox: 0, oy: 0, fitted: true };
  }
  resize(); // the bars around the photo may have come or gone
  rebuildMask();
  renderRefs();
  update();
}

async function addRefs(files) {
  const errors = [];
  for (const file of files) {
    let bitmap;
    try {
      bitmap = await decode(file); // refuse now what the browser cannot show as a thumbnail
    } catch (e) {
      errors.push(e.message);
      continue;
    }
    const thumb = document.createElement("canvas");
    const s = Math.min(1, THUMB_SIDE / Math.max(bitmap.width, bitmap.height));
    thumb.width = Math.max(1, Math.round(bitmap.width * s));
    thumb.height = Math.max(1, Math.round(bitmap.height * s));
    state.refs.push({ file, url: URL.createObjectURL(file), layer: newLayer(bitmap, KEEP_OUT_RGB), thumb });
    state.refsVersion++;
  }
  say(errors.join(" ")); // an earlier file's error no longer applies
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
  say(""); // an earlier file's error no longer applies
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

// The canvas's bitmap takes its box's size in device px (so the photo keeps its shape); a fitted
// photo is fitted again, a zoomed one keeps the point at the centre.
function resize() {
  const dpr = window.devicePixelRatio || 1;
  const box = canvasBox.getBoundingClientRect();
  const width = Math.max(1, Math.round(box.width * dpr));
  const height = Math.max(1, Math.round(box.height * dpr));
  if (width !== view.width || height !== view.height) {
    const [cx, cy] = toImage(view.width / 2, view.height / 2);
    view.width = width;
    view.height = height;
    const v = state.view;
    v.ox = width / 2 - cx * v.scale;
    v.oy = height / 2 - cy * v.scale;
  }
  if (state.view.fitted) fit();
  else render();
}

function fit() {
  if (!state.doc) return;
  const { width, height } = state.doc.bitmap;
  const s = Math.min(view.width / width, view.height / height);
  state.view = { scale: s, ox: (view.width - width * s) / 2, oy: (view.height - height * s) / 2, fitted: true };
  render();
}

function zoomAt(factor, cx = view.width / 2, cy = view.height / 2) {
  const v = state.view;
  const s = Math.min(Math.max(v.scale * factor, 0.02), 32);
  v.ox = cx - ((cx - v.ox) * s) / v.scale;
  v.oy = cy - ((cy - v.oy) * s) / v.scale;
  v.scale = s;
  v.fitted = false;
  render();
}

function panBy(dx, dy) {
  state.view.ox += dx;
  state.view.oy += dy;
  state.view.fitted = false;
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
    // Before | after: the photo left of the divider, the result right of it.
    const split = (Number($("split").value) / 100) * width;
    ctx.save();
    ctx.beginPath();
    ctx.rect(split, 0, width - split, height);
    ctx.clip();
    ctx.drawImage(state.result.bitmap, 0, 0);
    if ($("show-coverage").checked) ctx.drawImage(state.result.coverage, 0, 0);
    ctx.restore();
    ctx.fillStyle = "#fff";
    ctx.fillRect(split - 1 / v.scale, 0, 2 / v.scale, height);
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    dividerLabels(v.ox + split * v.scale, Math.max(v.oy, 0));
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

// "Before" and "After" beside the divider's top (x, y in canvas px), each on its own side.
function dividerLabels(x, y) {
  const dpr = window.devicePixelRatio || 1;
  const pad = 6 * dpr;
  ctx.font = `600 ${12 * dpr}px system-ui, sans-serif`;
  ctx.textBaseline = "top";
  for (const [text, side] of [["Before", -1], ["After", 1]]) {
    const w = ctx.measureText(text).width + 2 * pad;
    const left = side < 0 ? x - pad - w : x + pad;
    ctx.fillStyle = "rgba(0, 0, 0, 0.6)";
    ctx.fillRect(left, y + pad, w, 18 * dpr);
    ctx.fillStyle = "#fff";
    ctx.fillText(text, left + pad, y + pad + 3 * dpr);
  }
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

// Two fingers on a touch screen zoom and pan (a stroke the first finger began is dropped).
const touches = new Map(); // pointerId -> [x, y] in canvas px
let pinch = null; // {d, x, y}: the fingers' distance and midpoint at the last move

function pinchOf() {
  const [[ax, ay], [bx, by]] = [...touches.values()];
  return { d: Math.max(Math.hypot(bx - ax, by - ay), 1), x: (ax + bx) / 2, y: (ay + by) / 2 };
}

view.addEventListener("pointerdown", (e) => {
  if (!state.doc) return;
  view.focus();
  view.setPointerCapture(e.pointerId);
  const [x, y] = canvasPoint(e);
  if (e.pointerType === "touch") {
    touches.set(e.pointerId, [x, y]);
    if (touches.size >= 2) {
      if (state.stroke) {
        state.stroke = null;
        rebuildMask();
      }
      state.pan = null;
      pinch = touches.size === 2 ? pinchOf() : null;
      return;
    }
  }
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
  if (touches.has(e.pointerId)) touches.set(e.pointerId, [x, y]);
  if (pinch && touches.size === 2) {
    const now = pinchOf();
    panBy(now.x - pinch.x, now.y - pinch.y);
    zoomAt(now.d / pinch.d, now.x, now.y);
    pinch = now;
    return;
  }
  state.pointer = [x, y];
  if (state.pan) {
    state.view.ox = state.pan.ox + x - state.pan.x;
    state.view.oy = state.pan.oy + y - state.pan.y;
    state.view.fitted = false;
  } else if (state.stroke) {
    state.stroke.points.push(toImage(x, y));
    const p = state.stroke.points;
    drawOp({ ...state.stroke, points: p.slice(-2) }); // only the new segment; replay draws it whole
  }
  render();
});

function endPointer(e) {
  touches.delete(e.pointerId);
  if (pinch || touches.size) {
    pinch = null; // the fingers left after a pinch neither draw nor pan
    return;
  }
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

// Plain titles of the config's sections (the server lists them in the pipeline's order); "" holds
// the top-level keys.
const SECTION_TITLES = {
  intrinsics: "Camera focal length",
  matching: "Matching points between the photos",
  geometry: "Camera positions",
  depth: "Depth of the reference",
  optimize: "Fine alignment of position and depth",
  render: "Rendering the reference",
  inpaint: "Painting what no reference shows",
  refine: "Alignment and colour match",
  fusion: "Combining several references",
  screen: "What may be copied",
  "": "Limits and speed",
};

// ``code`` and :role:`code` in a description (the config's docstring markup) as <code>.
function richText(el, text) {
  const parts = text.split(/``([^`]+)``|:[a-z]+:`([^`]+)`/);
  parts.forEach((part, i) => {
    if (part === undefined || part === "") return;
    if (i % 3 === 0) el.append(part);
    else el.append(Object.assign(document.createElement("code"), { textContent: part }));
  });
}

const number = (x) => (Math.abs(x) >= 1e4 ? x.toLocaleString("en") : String(x));

// "0 to 1", "above 0, up to 10": a number's bounds in words.
function rangeText(r) {
  const lo = r.lo_open ? `above ${number(r.lo)}` : `${number(r.lo)}`;
  const hi = r.hi_open ? `below ${number(r.hi)}` : `${r.lo_open ? "up to " : "to "}${number(r.hi)}`;
  return r.lo_open || r.hi_open ? `${lo}, ${hi}` : `${lo} ${hi}`;
}

// What a field allows and its default, in words.
function limitsText(f) {
  const shown = (v) => (v === null ? "automatic" : Array.isArray(v) ? v.join(", ") : String(v));
  const parts = [`Default: ${shown(f.default)}`];
  if (f.kind === "list") {
    const [lo, hi] = f.length || [];
    const count = f.length ? (lo === hi ? `${lo} values` : `${lo} to ${hi} values`) : "values";
    parts.push(f.range ? `${count}, each ${rangeText(f.range)}` : count);
  } else if (f.range) parts.push(rangeText(f.range));
  if (f.cap !== null && f.cap !== undefined && !(f.zero_is_most && f.cap === 0)) {
    // the server's cap on a setting that costs: a request may lower it, not raise it
    const each = f.kind === "list" ? "each " : "";
    parts.push(`this server allows ${each}at most ${number(f.cap)}${f.zero_is_most ? " (0, no limit, is refused)" : ""}`);
  }
  if (f.optional && f.kind !== "list") parts.push("empty: automatic");
  return `${parts.join(" · ")}.`;
}

function fieldInput(f) {
  let input;
  if (f.kind === "choice") {
    input = document.createElement("select");
    for (const c of f.choices) input.append(new Option(String(c), JSON.stringify(c)));
  } else if (f.kind === "bool") {
    input = document.createElement("input");
    input.type = "checkbox";
  } else {
    input = document.createElement("input");
    const numeric = f.kind === "int" || f.kind === "float";
    input.type = numeric ? "number" : "text";
    if (numeric) input.step = f.kind === "int" ? "1" : "any";
    if (numeric && f.range) {
      const capped = f.cap !== null && f.cap !== undefined && !(f.zero_is_most && f.cap === 0);
      input.min = capped && f.zero_is_most ? Math.max(f.range.lo, 1) : f.range.lo;
      input.max = capped ? Math.min(f.range.hi, f.cap) : f.range.hi;
    }
    if (f.optional) input.placeholder = "automatic";
  }
  input.id = `cfg-${f.key}`;
  setFieldValue(f, input, f.default);
  return input;
}

function setFieldValue(f, input, value) {
  if (f.kind === "bool") input.checked = value;
  else if (f.kind === "choice") input.value = JSON.stringify(value);
  else input.value = value === null ? "" : f.kind === "list" ? value.join(", ") : String(value);
}

// One option: its name, its input, its description, what it allows and its default.
function fieldRow(f, fullKey) {
  const row = document.createElement("div");
  row.className = "field";
  row.dataset.key = f.key;
  const input = fieldInput(f);
  const label = document.createElement("label");
  label.htmlFor = input.id;
  const name = document.createElement("code");
  // a long key may wrap after a dot or an underscore, not inside a word
  (fullKey ? f.key : f.key.split(".").pop()).split(/(?<=[._])/).forEach((part, i) => {
    if (i) name.append(document.createElement("wbr"));
    name.append(part);
  });
  label.append(name);
  const about = document.createElement("p");
  richText(about, f.description);
  about.id = `${input.id}-about`;
  const limits = Object.assign(document.createElement("p"), { className: "limits", textContent: limitsText(f) });
  input.setAttribute("aria-describedby", about.id);
  input.addEventListener("change", optionsChanged);
  row.append(label, input, about, limits);
  f.input = input;
  f.row = row;
  return row;
}

async function loadFields() {
  const resp = await fetch("/api/v1/config/fields");
  if (!resp.ok) return;
  const { fields, sections, common } = await resp.json();
  state.fields = fields.filter((f) => !f.locked);
  const box = $("advanced-fields");
  const byKey = new Map(state.fields.map((f) => [f.key, f]));
  const first = common.filter((k) => byKey.has(k));
  if (first.length) {
    box.append(Object.assign(document.createElement("h3"), { textContent: "Most often changed" }));
    for (const key of first) box.append(fieldRow(byKey.get(key), true));
  }
  const groups = [...sections, { key: "", description: "" }];
  state.sections = [];
  for (const { key, description } of groups) {
    const members = state.fields.filter((f) => f.section === key && !first.includes(f.key));
    if (!members.length) continue;
    const details = document.createElement("details");
    details.dataset.section = key;
    const summary = document.createElement("summary");
    const count = Object.assign(document.createElement("span"), { className: "count" });
    summary.append(`${SECTION_TITLES[key] || key} `, count);
    details.append(summary);
    if (description) {
      const about = Object.assign(document.createElement("p"), { className: "hint about" });
      richText(about, key ? `${key}: ${description}` : description);
      details.append(about);
    }
    for (const f of members) details.append(fieldRow(f, false));
    state.sections.push({ details, count, members });
    box.append(details);
  }
  optionsChanged();
}

// Marks the options that differ from their defaults, and counts them per section.
function optionsChanged() {
  let any = false;
  for (const f of state.fields) {
    const { changed } = fieldValue(f, f.input);
    f.row.classList.toggle("changed", changed);
    any ||= changed;
  }
  for (const { count, members } of state.sections) {
    const changed = members.filter((f) => f.row.classList.contains("changed")).length;
    count.textContent = changed ? `(${members.length}, ${changed} changed)` : `(${members.length})`;
    count.classList.toggle("changed", changed > 0);
  }
  $("advanced-reset").disabled = !any;
}

// Shows only the options whose name or description has every word typed, opening their sections.
function filterOptions() {
  const words = $("advanced-filter").value.toLowerCase().split(/\s+/).filter(Boolean);
  for (const f of state.fields) {
    const text = `${f.key} ${f.description}`.toLowerCase();
    f.row.hidden = !words.every((w) => text.includes(w));
  }
  for (const { details, members } of state.sections) {
    const shown = members.some((f) => !f.row.hidden);
    details.hidden = !shown;
    details.open = words.length > 0 && shown;
  }
}

function resetOptions() {
  for (const f of state.fields) setFieldValue(f, f.input, f.default);
  optionsChanged();
}

function fieldValue(f, input) {
  let value;
  const text = input.value.trim();
  if (f.kind === "bool") value = input.checked;
  else if (f.kind === "choice") value = JSON.parse(input.value);
  else if (text === "" && f.optional) value = null;
  else if (f.kind === "int" || f.kind === "float") {
    // Not a number (the browser then reads ""): sent as such, the server's 422 names the key.
    value = input.validity.badInput || text === "" ? "not a number" : Number(text);
  } else if (f.kind === "list") {
    const items = text.replace(/^\[|\]$/g, "").split(/[\s,]+/).filter(Boolean);
    value = items.map(Number);
    if (value.some(Number.isNaN)) value = input.value;
  } else value = input.value;
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
    // Lossless for the preview and for "Keep editing" (no JPEG generation loss between edits).
    result = await fetchBitmap(`/api/v1/jobs/${id}/result?format=png`);
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
  // The download keeps the photo's own format (a JPEG at its own quality, EXIF kept).
  $("download").href = `/api/v1/jobs/${id}/result`;
  $("download").download = `geofill-${job.result_file || "result.png"}`;
  $("result").hidden = false;
  $("compare").hidden = !isTarget(state.doc);
  $("split").value = dividerStart();
  resize();
  update();
  $("result").scrollIntoView({ block: "nearest" });
}

// Where the divider starts (% of the width): at the hole's left edge, so that all of the fill shows,
// and at most half-way, so that the photo before shows too.
function dividerStart() {
  const mask = state.target.layer.mask;
  const w = Math.min(256, mask.width);
  const h = Math.max(1, Math.round((mask.height * w) / mask.width));
  const small = document.createElement("canvas");
  small.width = w;
  small.height = h;
  const sctx = small.getContext("2d");
  sctx.drawImage(mask, 0, 0, w, h);
  const alpha = sctx.getImageData(0, 0, w, h).data;
  let left = w;
  for (let i = 3; i < alpha.length; i += 4) if (alpha[i] > 0) left = Math.min(left, ((i - 3) / 4) % w);
  return Math.min(50, Math.floor((100 * left) / w));
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
// Whatever changes the editor's size (the window, a bar shown or hidden, the panel's content on
// one column) sizes the canvas's bitmap again.
new ResizeObserver(() => { if (state.doc) resize(); }).observe(canvasBox);
$("advanced-filter").addEventListener("input", filterOptions);
$("advanced-reset").addEventListener("click", resetOptions);
loadFields();
update();
