// prt view's page: controls built from /api/spec (the method's declared run-time edits
// and options; no method is named here), frames over a WebSocket, a readout of where
// each frame's time went. window.prtView exposes the measurements to tests and the
// benchmark (benchmarks/view/latency.py).
"use strict";

const $ = (id) => document.getElementById(id);
let spec = null;
let ws = null;
let nextId = 1;
let lastPainted = 0;
let lastInput = performance.now();
const sent = new Map();           // id -> {t: sent, input: input event time}
const painted = [];               // per frame painted: the measurements
const paintTimes = [];            // for fps
const edits = {lights: {}, environment: null, environment_scale: null, camera: null,
               materials: {}, options: {}};
let exposure = 0;
let format = "jpeg";
let view = "frame";
let lastHeader = null;
let dragTarget = null;
const MIME = {jpeg: "image/jpeg", webp: "image/webp", png: "image/png"};

window.prtView = {painted, edits, get last() { return lastHeader; },
                  get lastPainted() { return lastPainted; }, errors: [],
                  set: setControl, request, reset: () => location.reload()};

function el(tag, props = {}, children = []) {
  const e = document.createElement(tag);
  Object.assign(e, props);
  for (const c of children) e.append(c);
  return e;
}

function fmt(x, digits = 3) {
  return Math.abs(x) >= 1000 ? x.toFixed(0) : Number(x.toPrecision(digits)).toString();
}

// a slider: value shown beside it; input events are drags, change is the release
function slider(parent, id, text, min, max, step, value, group, onValue, show = fmt) {
  const input = el("input", {type: "range", id, min, max, step, value});
  const out = el("output", {value: show(Number(value))});
  input.dataset.group = group;
  input.addEventListener("input", () => {
    lastInput = performance.now();
    onValue(Number(input.value));
    out.value = show(Number(input.value));
    request(true, group);
  });
  input.addEventListener("change", () => {
    onValue(Number(input.value));
    out.value = show(Number(input.value));
    request(false, group);
  });
  parent.append(el("label", {}, [el("span", {textContent: text}), input, out]));
  return input;
}

function setControl(id, value) {          // for tests: move a control as a user would
  const input = $(id);
  input.value = value;
  input.dispatchEvent(new Event("input", {bubbles: true}));
  input.dispatchEvent(new Event("change", {bubbles: true}));
  return nextId - 1;
}

function fieldset(title) {
  const f = el("fieldset", {}, [el("legend", {textContent: title})]);
  $("controls").append(f);
  return f;
}

function build() {
  $("title").textContent = `${spec.scene} · method ${spec.method}: ${spec.description}` +
    ` · ${spec.width}×${spec.height}`;
  format = spec.format;
  $("notices").textContent = (spec.notices || []).join("\n");  // once, as the console
  const vc = $("view-controls");
  const fsel = el("select", {id: "format"}, spec.formats.map(
    (f) => el("option", {value: f, textContent: f, selected: f === format})));
  fsel.addEventListener("change", () => { format = fsel.value; request(false); });
  vc.append(el("label", {}, [el("span", {textContent: "frames as"}), fsel, el("span")]));
  const vsel = el("select", {id: "view"}, ["frame", "side by side", "difference"].map(
    (v) => el("option", {value: v, textContent: v})));
  vsel.addEventListener("change", () => { view = vsel.value; showSecond(); });
  vc.append(el("label", {}, [el("span", {textContent: "reference"}), vsel, el("span")]));
  exposure = spec.exposure;
  slider(vc, "exposure", "exposure EV", -16, 16, 0.1, exposure, "exposure",
         (v) => { exposure = v; });
  const targets = [];
  const dsel = el("select", {id: "drag"});
  vc.append(el("label", {}, [el("span", {textContent: "drag moves"}), dsel, el("span")]));

  for (const light of spec.lights) {
    const f = fieldset(`light ${light.index} (${light.type})`);
    edits.lights[light.index] = [0, 0, 0];
    ["x", "y", "z"].forEach((axis, k) => slider(
      f, `light-${light.index}-${axis}`, `move ${axis}`, -spec.reach, spec.reach,
      spec.reach / 500, 0, "light", (v) => { edits.lights[light.index][k] = v; }));
    targets.push([`light ${light.index}`, {kind: "light", index: light.index}]);
  }
  if (spec.environment) {
    const f = fieldset("environment");
    if (spec.environment.rotation !== null) {
      edits.environment = spec.environment.rotation;
      slider(f, "environment", "rotation °", -360, 360, 0.5, spec.environment.rotation,
             "environment", (v) => { edits.environment = v; });
      targets.push(["environment", {kind: "environment"}]);
    }
    if (spec.environment.scale !== null) {    // in stops about the file's scale
      const base = spec.environment.scale || 1;
      const toScale = (t) => (t === 0 ? spec.environment.scale : base * Math.pow(2, t));
      edits.environment_scale = spec.environment.scale;
      slider(f, "environment-scale", "scale ×", -8, 8, 0.05, 0, "environment",
             (t) => { edits.environment_scale = toScale(t); }, (t) => fmt(toScale(t)));
    }
  }
  if (spec.camera.orbit) {
    const f = fieldset("camera orbit");
    edits.camera = [0, 0];
    slider(f, "camera-azimuth", "azimuth °", -180, 180, 0.5, 0, "camera",
           (v) => { edits.camera[0] = v; });
    slider(f, "camera-elevation", "elevation °", -spec.camera.limit - spec.camera.elevation,
           spec.camera.limit - spec.camera.elevation, 0.5, 0, "camera",
           (v) => { edits.camera[1] = v; });
    targets.push(["camera", {kind: "camera"}]);
  }
  for (const m of spec.materials) {
    const f = fieldset(`material ${m.name} (${m.model})`);
    const mine = edits.materials[m.name] = {};
    if (m.keys.includes("gamma")) {
      const [lo, hi] = m.gamma_range;
      const toGamma = (t) => lo * Math.pow(hi / lo, t / 1000);
      const start = 1000 * Math.log(m.gamma / lo) / Math.log(hi / lo);
      slider(f, `mat-${m.name}-gamma`, `γ ${fmt(lo)}–${fmt(hi)}`, 0, 1000, 1, start, "gamma",
             (t) => { mine.gamma = Math.min(hi, Math.max(lo, toGamma(t))); },
             (t) => fmt(toGamma(t)));
    }
    if (m.keys.includes("specular")) {
      slider(f, `mat-${m.name}-specular`, "ρs", 0, 1, 0.005, m.specular, "specular",
             (v) => { mine.specular = v; });
    }
    if (m.keys.includes("albedo")) {
      ["r", "g", "b"].forEach((c, k) => slider(
        f, `mat-${m.name}-albedo-${c}`, `albedo ${c}`, 0, 1, 0.005, m.albedo[k], "albedo",
        (v) => { mine.albedo = (mine.albedo || m.albedo.slice()); mine.albedo[k] = v; }));
    }
  }
  if (spec.options.length) {
    const f = fieldset("options");
    for (const o of spec.options) {
      let input;
      if (o.choices.length) {
        input = el("select", {id: `opt-${o.name}`}, o.choices.map(
          (c) => el("option", {value: c, textContent: c, selected: c === o.default})));
      } else {
        input = el("input", {id: `opt-${o.name}`, type: "number", value: o.default,
                             step: o.type === "int" ? 1 : "any"});
        if (o.least !== null) input.min = o.least;
      }
      input.title = o.help + (o.name in spec.drag_options ?
        ` (while dragging: ${spec.drag_options[o.name]})` : "");
      input.addEventListener("change", () => {
        if (String(input.value) === String(o.default)) delete edits.options[o.name];
        else edits.options[o.name] = input.value;
        request(false, "option");
      });
      f.append(el("label", {title: input.title}, [el("span", {textContent: o.name}), input,
                                                  el("span")]));
    }
  }
  for (const [text, target] of targets) {
    dsel.append(el("option", {value: JSON.stringify(target), textContent: text}));
  }
  if (!targets.length) dsel.append(el("option", {value: "null", textContent: "nothing"}));
  const canvas = $("frame");
  canvas.width = spec.width;
  canvas.height = spec.height;
  const scale = Math.max(1, Math.floor(512 / Math.max(spec.width, spec.height)));
  canvas.style.width = `${spec.width * scale}px`;
  canvas.style.height = `${spec.height * scale}px`;
  setupDrag(canvas, dsel);
  $("save").addEventListener("click", save);
  $("copy").addEventListener("click", () => navigator.clipboard?.writeText($("command").value));
  $("reset").addEventListener("click", () => location.reload());
}

// dragging on the image moves the chosen target (a light in the image plane, the
// environment's turn, the camera's orbit)
function setupDrag(canvas, dsel) {
  let last = null;
  canvas.addEventListener("pointerdown", (e) => {
    dragTarget = JSON.parse(dsel.value);
    if (!dragTarget) return;
    canvas.setPointerCapture(e.pointerId);
    last = [e.clientX, e.clientY];
  });
  canvas.addEventListener("pointermove", (e) => {
    if (!last || !dragTarget) return;
    lastInput = performance.now();
    const rect = canvas.getBoundingClientRect();
    const dx = (e.clientX - last[0]) / rect.width;
    const dy = (e.clientY - last[1]) / rect.height;
    last = [e.clientX, e.clientY];
    const t = dragTarget;
    if (t.kind === "light") {
      const d = edits.lights[t.index];
      for (let k = 0; k < 3; k++) {
        const step = 0.5 * (dx * spec.camera.right[k] - dy * spec.camera.up[k]) * spec.diagonal;
        d[k] = Math.max(-spec.reach, Math.min(spec.reach, d[k] + step));
        syncSlider(`light-${t.index}-${"xyz"[k]}`, d[k]);
      }
    } else if (t.kind === "environment") {
      edits.environment = ((edits.environment + 360 * dx + 360) % 720) - 360;
      syncSlider("environment", edits.environment);
    } else if (t.kind === "camera") {
      const lo = -spec.camera.limit - spec.camera.elevation;
      const hi = spec.camera.limit - spec.camera.elevation;
      edits.camera[0] = ((edits.camera[0] - 180 * dx + 540) % 360) - 180;
      edits.camera[1] = Math.max(lo, Math.min(hi, edits.camera[1] + 90 * dy));
      syncSlider("camera-azimuth", edits.camera[0]);
      syncSlider("camera-elevation", edits.camera[1]);
    }
    request(true, t.kind);
  });
  const up = () => {
    if (last && dragTarget) request(false, dragTarget.kind);
    last = null;
  };
  canvas.addEventListener("pointerup", up);
  canvas.addEventListener("pointercancel", up);
}

function syncSlider(id, value) {
  const input = $(id);
  input.value = value;
  input.parentElement.querySelector("output").value = fmt(Number(value));
}

function request(dragging, control = null) {
  if (!ws || ws.readyState !== WebSocket.OPEN) return;
  if (control === "exposure") dragging = false;   // a new tone mapping of a cached frame
  const id = nextId++;
  sent.set(id, {t: performance.now(), input: dragging ? lastInput : performance.now(),
                dragging});
  ws.send(JSON.stringify({type: "frame", id, edits, dragging, control, format, exposure}));
  return id;
}

function connect() {
  ws = new WebSocket(`ws://${location.host}/ws`);
  ws.binaryType = "arraybuffer";
  ws.onopen = () => request(false);
  ws.onclose = () => { $("readout").textContent = "disconnected (is prt view running?)"; };
  ws.onmessage = async (msg) => {
    const received = performance.now();
    if (typeof msg.data === "string") {
      const body = JSON.parse(msg.data);
      $("error").textContent = body.message;
      window.prtView.errors.push(body);
      sent.delete(body.id);
      return;
    }
    const n = new DataView(msg.data).getUint32(0, true);
    const header = JSON.parse(new TextDecoder().decode(new Uint8Array(msg.data, 4, n)));
    const payload = new Uint8Array(msg.data, 4 + n);
    const s = sent.get(header.id);
    sent.delete(header.id);
    if (header.id < lastPainted || !s) return;       // an older frame: never painted over
    const image = await decode(header, payload);
    // frames decode concurrently: one sent later may have been painted meanwhile
    if (header.id < lastPainted) { if (image.close) image.close(); return; }
    draw(image);
    const done = performance.now();
    lastPainted = header.id;
    lastHeader = header;
    $("error").textContent = "";
    $("command").value = header.command;
    paintTimes.push(done);
    while (paintTimes.length && paintTimes[0] < done - 1000) paintTimes.shift();
    const m = {id: header.id, dragging: header.dragging, mode: header.mode,
               cached: header.cached, render_ms: header.render_ms,
               encode_ms: header.encode_ms, queue_ms: header.queue_ms,
               transfer_ms: Math.max(0, received - s.t - header.server_ms),
               paint_ms: done - received, latency_ms: done - s.input, bytes: header.bytes,
               format: header.format, t: done};
    painted.push(m);
    if (painted.length > 5000) painted.shift();
    $("readout").textContent =
      `render ${m.render_ms.toFixed(1)} ms${m.cached ? " (cached)" : ""} · encode ` +
      `${m.encode_ms.toFixed(1)} ms · transfer ${m.transfer_ms.toFixed(1)} ms · paint ` +
      `${m.paint_ms.toFixed(1)} ms\nlatency ${m.latency_ms.toFixed(1)} ms · ` +
      `${paintTimes.length} fps · ${header.mode}${header.dragging ? " (dragging)" : ""} · ` +
      `${(m.bytes / 1024).toFixed(1)} KiB ${header.format}`;
    $("view").disabled = false;
    if (view !== "frame" && !header.dragging) showSecond();
  };
}

let lut = null;
let lutExposure = null;

function halfToFloat(h) {
  const s = h & 0x8000 ? -1 : 1;
  const e = (h >> 10) & 0x1f;
  const f = h & 0x3ff;
  if (e === 0) return s * f * Math.pow(2, -24);
  if (e === 31) return f ? NaN : s * Infinity;
  return s * (1 + f / 1024) * Math.pow(2, e - 15);
}

function srgb8(x) {             // pipeline/images.py srgb_encode, to 8 bits
  x = Math.min(1, Math.max(0, x));
  const v = x <= 0.0031308 ? 12.92 * x : 1.055 * Math.pow(x, 1 / 2.4) - 0.055;
  return Math.round(v * 255);
}

// a frame's pixels, ready to draw: ImageData (float16, tone-mapped here) or an ImageBitmap
async function decode(header, payload) {
  if (header.format === "f16") {      // linear half floats: tone-mapped here
    if (lutExposure !== exposure) {
      lut = new Uint8Array(65536);
      const scale = Math.pow(2, exposure);
      for (let h = 0; h < 65536; h++) lut[h] = srgb8(halfToFloat(h) * scale);
      lutExposure = exposure;
    }
    const half = new Uint16Array(payload.buffer.slice(payload.byteOffset,
                                                      payload.byteOffset + payload.byteLength));
    const image = new ImageData(header.width, header.height);
    const px = image.data;
    for (let i = 0, j = 0; i < half.length; i += 3, j += 4) {
      px[j] = lut[half[i]]; px[j + 1] = lut[half[i + 1]]; px[j + 2] = lut[half[i + 2]];
      px[j + 3] = 255;
    }
    return image;
  }
  return createImageBitmap(new Blob([payload], {type: MIME[header.format]}),
                           {colorSpaceConversion: "none", premultiplyAlpha: "none"});
}

function draw(image) {
  const ctx = $("frame").getContext("2d");
  if (image instanceof ImageData) { ctx.putImageData(image, 0, 0); return; }
  ctx.drawImage(image, 0, 0);
  image.close();
}

async function showSecond() {
  const second = $("second");
  if (view === "frame") { second.hidden = true; return; }
  const response = await fetch("/api/reference", {
    method: "POST", body: JSON.stringify({edits, exposure,
                                          view: view === "difference" ? "difference" : "reference"})});
  if (!response.ok) {
    second.hidden = true;
    $("error").textContent = (await response.json()).error;
    return;
  }
  const bitmap = await createImageBitmap(await response.blob());
  second.width = bitmap.width;
  second.height = bitmap.height;
  second.style.width = $("frame").style.width;
  second.style.height = $("frame").style.height;
  second.getContext("2d").drawImage(bitmap, 0, 0);
  second.hidden = false;
}

async function save() {
  $("saved").textContent = "saving…";
  const response = await fetch("/api/save", {method: "POST",
                                             body: JSON.stringify({edits, exposure})});
  const body = await response.json();
  window.prtView.saved = body;
  if (!response.ok) {
    $("saved").textContent = "";
    $("error").textContent = body.error;
    return;
  }
  $("saved").textContent = `saved ${body.exr}, ${body.png} and ${body.edits_json}\n` +
    `the same bytes: ${body.command}`;
}

fetch("/api/spec").then((r) => r.json()).then((s) => { spec = s; build(); connect(); })
  .catch((e) => { $("error").textContent = `error: cannot load the viewer (${e})`; });
