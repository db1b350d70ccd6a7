// sonoslice view — the browser side of `sonoslice view`.
//
// Talks only to the same origin through the HTTP API of src/view/ViewServer.cpp (scene JSON,
// float32 planes and images, poses, mask, meshes, live status). World frame: LPS millimetres.
// Scene matrices are row-major 4x4 (as the server sends them); only the GL view-projection is
// column-major. Panels: three orthogonal planes (Canvas 2D), a 3-D scene (WebGL2, optional) and
// the ultrasound image. window.sonosliceView exposes state and hooks for the browser tests.
'use strict';

(() => {

// ===================================================================================== helpers

const $ = (id) => document.getElementById(id);
const clamp = (x, lo, hi) => Math.min(hi, Math.max(lo, x));
const now = () => performance.now();
const noop = () => {};
// UI-initiated loads: their errors are already shown in the status line, nothing to do here.
const quiet = (p) => p.catch(noop);

function pushStat(list, value) {
  list.push(value);
  if (list.length > 10000) list.splice(0, list.length - 10000);  // bounded for long live runs
}

// Problems go to the status line, never to the console (the tests require a clean console).
function setStatus(text, isError = false) {
  const el = $('status');
  el.textContent = text;
  el.title = text;
  el.classList.toggle('error', isError);
}
function reportError(where, err) {
  setStatus(`${where}: ${err && err.message ? err.message : String(err)}`, true);
}

async function fetchOk(url) {
  const r = await fetch(url, {cache: 'no-store'});
  if (!r.ok) {
    let detail = '';
    try { detail = (await r.text()).slice(0, 200); } catch (e) { /* body unreadable: keep the code */ }
    throw new Error(`${url.split('?')[0]} → HTTP ${r.status}${detail ? ': ' + detail : ''}`);
  }
  return r;
}
async function fetchJSON(url) { return (await fetchOk(url)).json(); }
// Binary bodies are little-endian float32 (all browsers the viewer targets are little-endian).
async function fetchF32(url, count) {
  const buf = await (await fetchOk(url)).arrayBuffer();
  if (count != null && buf.byteLength !== 4 * count) {
    throw new Error(`${url.split('?')[0]}: expected ${4 * count} bytes, got ${buf.byteLength}`);
  }
  return new Float32Array(buf);
}

// Writes an element's text only when it changed: a write invalidates the page's layout.
function setText(el, text) {
  if (el.textContent !== text) el.textContent = text;
}

// ---- 3-vectors
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const mul = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const len = (a) => Math.hypot(a[0], a[1], a[2]);
const normalize = (a) => { const n = len(a) || 1; return [a[0] / n, a[1] / n, a[2] / n]; };
function rotateAbout(v, k, ang) {  // Rodrigues; k is a unit axis
  const c = Math.cos(ang), s = Math.sin(ang), kv = cross(k, v), kd = dot(k, v) * (1 - c);
  return [v[0] * c + kv[0] * s + k[0] * kd, v[1] * c + kv[1] * s + k[1] * kd, v[2] * c + kv[2] * s + k[2] * kd];
}

// ---- row-major 4x4 (scene matrices: poses, pixel_to_probe, frame matrices)
function rmMul(a, b) {
  const o = new Array(16);
  for (let r = 0; r < 4; r++) {
    for (let c = 0; c < 4; c++) {
      o[4 * r + c] = a[4 * r] * b[c] + a[4 * r + 1] * b[4 + c] + a[4 * r + 2] * b[8 + c] + a[4 * r + 3] * b[12 + c];
    }
  }
  return o;
}
const rmApply = (m, x, y, z) => [
  m[0] * x + m[1] * y + m[2] * z + m[3],
  m[4] * x + m[5] * y + m[6] * z + m[7],
  m[8] * x + m[9] * y + m[10] * z + m[11]];
const rmColumnNorm = (m, c) => Math.hypot(m[c], m[4 + c], m[8 + c]);

// ---- column-major 4x4 (what WebGL takes): the standard OpenGL perspective and lookAt
function perspective(fovy, aspect, near, far) {
  const f = 1 / Math.tan(fovy / 2), nf = 1 / (near - far);
  return [f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0];
}
function lookAt(eye, target, up) {
  const f = normalize(sub(target, eye)), s = normalize(cross(f, up)), u = cross(s, f);
  return [s[0], u[0], -f[0], 0, s[1], u[1], -f[1], 0, s[2], u[2], -f[2], 0,
    -dot(s, eye), -dot(u, eye), dot(f, eye), 1];
}
function cmMul(a, b) {
  const o = new Array(16);
  for (let c = 0; c < 4; c++) {
    for (let r = 0; r < 4; r++) {
      o[4 * c + r] = a[r] * b[4 * c] + a[4 + r] * b[4 * c + 1] + a[8 + r] * b[4 * c + 2] + a[12 + r] * b[4 * c + 3];
    }
  }
  return o;
}

// ---- windowing: the contract's formula, evaluated in exactly its order (lo, scale, clamp, round),
// so that the tests can compare pixels bit for bit.
// One 32-bit store a pixel (RGBA bytes in memory order); 8-bit values (live frames as received)
// through a 256-entry table of the same formula. A live page does this for every frame, so it is
// the page's main cost per frame.
const LITTLE_ENDIAN = new Uint8Array(new Uint32Array([1]).buffer)[0] === 1;
const grayPixel = (g) => LITTLE_ENDIAN ? (0xff000000 | (g << 16) | (g << 8) | g) >>> 0 : ((g << 24) | (g << 16) | (g << 8) | 0xff) >>> 0;
function windowInto(rgba, values, level, width) {
  const lo = level - width / 2, scale = 255 / width, n = values.length;
  const gray = (v) => v !== v ? 0 : Math.round(Math.min(255, Math.max(0, (v - lo) * scale)));
  const out = new Uint32Array(rgba.buffer, rgba.byteOffset, n);
  if (values instanceof Uint8Array) {
    const table = new Uint32Array(256);
    for (let v = 0; v < 256; v++) table[v] = grayPixel(gray(v));
    for (let i = 0; i < n; i++) out[i] = table[values[i]];
    return;
  }
  for (let i = 0; i < n; i++) out[i] = grayPixel(gray(values[i]));
}
// Labels over gray: 50/50 blend; over nothing (labels-only scene): the label colours on black.
function blendLabels(rgba, labels, colors, onBlack) {
  for (let i = 0, n = labels.length; i < n; i++) {
    const k = labels[i];
    if (!(k > 0)) continue;
    const col = colors[Math.round(k) - 1];
    if (!col) continue;
    const o = 4 * i;
    for (let c = 0; c < 3; c++) rgba[o + c] = onBlack ? col[c] : Math.round(0.5 * rgba[o + c] + 0.5 * col[c]);
  }
}

// Latest-wins loader: at most one request in flight; a request made meanwhile replaces the wanted
// key, and when the flight lands the newest key is fetched before anything is drawn. Every caller's
// promise settles when the newest key has been applied (or failed).
class Latest {
  constructor(name, fetchFn, applyFn) {
    Object.assign(this, {name, fetchFn, applyFn, gen: 0, key: null, t0: 0, busy: false, waiters: []});
  }
  request(key) {
    this.key = key;
    this.t0 = now();
    this.gen++;
    const p = new Promise((resolve, reject) => this.waiters.push({resolve, reject}));
    if (!this.busy) this.run();
    return p;
  }
  // Resolves when nothing is pending (never rejects).
  settled() {
    return this.busy ? new Promise((resolve) => this.waiters.push({resolve, reject: resolve})) : Promise.resolve();
  }
  async run() {
    this.busy = true;
    for (;;) {
      const gen = this.gen, key = this.key, t0 = this.t0;
      let result, error = null;
      try { result = await this.fetchFn(key); } catch (e) { error = e; }
      if (gen !== this.gen) continue;  // superseded in flight: fetch the newest instead
      const waiters = this.waiters;
      this.waiters = [];
      this.busy = false;
      if (!error) {
        try { this.applyFn(result, key, t0); } catch (e) { error = e; }
      }
      if (error) {
        reportError(this.name, error);
        for (const w of waiters) w.reject(error);
      } else {
        for (const w of waiters) w.resolve();
      }
      return;
    }
  }
}

// ================================================================================ state & hooks

const stats = {imageMs: [], planeMs: [], liveUpdates: 0, framesShown: 0, polls: 0};
const state = {
  pose: 0,
  positions: [0, 0, 0],
  window: [0, 1],
  imageWindow: [0, 1],
  showLabels: false,
  camera: {eye: [0, -500, 0], target: [0, 0, 0], up: [0, 0, 1], fovDeg: 30},
};
const view = window.sonosliceView = {
  ready: false, scene: null, webgl: false, state, stats,
  setPose, setPlane, setWindow, setImageWindow, setLabels, setCamera, render3d, projection,
};

let scene = null;
let labelsOnly = false;   // labels but no volume: the planes show label colours on black
let poses = null;         // Float32Array N*16, probe -> world, row-major
let mask = null;          // Uint8Array H*W of the probe image, 1 inside the fan
let meshes = [];          // {name, color, pos, nrm, idx, gl: {...}}
let probeOverride = null; // row-major matrix while the probe is being moved by hand
let cameraTouched = false;
let bounds = {center: [0, 0, 0], radius: 100};
const live = {sceneVer: null, volVer: null, seq: null, frame: null, running: true};

const hasPoses = () => !!(poses && poses.length >= 16);
const poseCount = () => (poses ? poses.length / 16 : 0);
const poseMatrix = (k) => Array.from(poses.subarray(16 * k, 16 * k + 16));
const hasPoseImages = () => !!(scene && scene.probe && scene.image_source && hasPoses());
const selectedMatrix = () => (hasPoses() ? probeOverride || poseMatrix(state.pose) : null);

// ======================================================================================= planes

// Slicer's colours: sagittal yellow, coronal green, axial red (crosshair lines and titles).
const AXIS_COLORS = ['#e6c84c', '#64bb5c', '#e0605a'];
const planes = [0, 1, 2].map(makePlane);  // indexed by axis
let hoveredAxis = null;

function makePlane(axis) {
  const panel = document.querySelector(`.plane-panel[data-axis="${axis}"]`);
  const pl = {
    axis, panel, def: null,
    stage: panel.querySelector('.stage'), note: panel.querySelector('.note'),
    canvas: $(`plane-${axis}`), overlay: $(`plane-${axis}-overlay`),
    img: null, vol: null, lab: null, drawnPos: null,
    rect: {x: 0, y: 0, w: 0, h: 0},      // the stage in panel CSS pixels
    tex: null, texDirty: false,
  };
  // CPU-backed: we only putImageData, and tests read the pixels back with getImageData.
  pl.ctx = pl.canvas.getContext('2d', {willReadFrequently: true});
  pl.octx = pl.overlay.getContext('2d');
  pl.loader = new Latest(`plane ${axis}`, () => fetchPlane(pl), (res, key, t0) => applyPlane(pl, res, t0));
  return pl;
}

// (Re)configure a plane for the current scene; keep its position when still within range.
function setupPlane(pl, def, keepPosition) {
  const prev = pl.def;
  pl.def = def || null;
  pl.note.hidden = !!def;
  pl.stage.hidden = !def;
  if (!def) {
    pl.note.textContent = scene && scene.live ? 'no volume yet' : 'no volume';
    pl.vol = pl.lab = pl.img = null;
    pl.drawnPos = null;
    return;
  }
  const pos = state.positions[pl.axis];
  if (!(keepPosition && prev && pos >= def.min && pos <= def.max)) state.positions[pl.axis] = def.position;
  if (!prev || prev.width !== def.width || prev.height !== def.height || !pl.img) {
    pl.canvas.width = def.width;
    pl.canvas.height = def.height;
    pl.img = pl.ctx.createImageData(def.width, def.height);
    pl.vol = pl.lab = null;
    pl.drawnPos = null;
  }
}

async function fetchPlane(pl) {
  const def = pl.def, pos = state.positions[pl.axis], n = def.width * def.height;
  const url = `/api/plane?axis=${pl.axis}&pos=${pos}&layer=`;
  const wantLabels = !!(scene.labels && state.showLabels);
  const [vol, lab] = await Promise.all([
    labelsOnly ? null : fetchF32(url + 'volume', n),
    wantLabels ? fetchF32(url + 'labels', n) : null]);
  return {def, pos, vol, lab};
}

function applyPlane(pl, res, t0) {
  if (res.def !== pl.def) return;  // the grid changed in flight; the new scene requests again
  pl.vol = res.vol;
  pl.lab = res.lab;
  pl.drawnPos = res.pos;
  drawPlane(pl);
  pushStat(stats.planeMs, now() - t0);
  drawOverlay(pl);  // the others' crosshairs moved when the position did (movePlane)
  markDirty();
}

function drawPlane(pl) {
  if (!pl.def || !pl.img || (!pl.vol && !pl.lab)) return;
  const rgba = pl.img.data;
  if (pl.vol) {
    windowInto(rgba, pl.vol, state.window[0], state.window[1]);
  } else {
    for (let o = 0; o < rgba.length; o += 4) { rgba[o] = rgba[o + 1] = rgba[o + 2] = 0; rgba[o + 3] = 255; }
  }
  if (state.showLabels && pl.lab && scene.labels) blendLabels(rgba, pl.lab, scene.labels.colors, !pl.vol);
  pl.ctx.putImageData(pl.img, 0, 0);
  pl.texDirty = true;
}

// Move a plane: crosshairs follow at once, the pixels when the (latest) fetch lands.
function movePlane(axis, pos) {
  const pl = planes[axis];
  if (!pl || !pl.def) return Promise.resolve();
  const d = pl.def;
  if (!Number.isFinite(Number(pos))) return Promise.reject(new Error(`plane ${axis}: position ${pos} is not a number`));
  state.positions[axis] = clamp(Number(pos), d.min, d.max);
  drawOverlays();
  return pl.loader.request(state.positions[axis]);
}
function scrollPlane(axis, dir) {
  const d = planes[axis].def;
  if (d) quiet(movePlane(axis, state.positions[axis] + dir * d.step));
}
const refreshPlanes = () => Promise.all(planes.filter((pl) => pl.def).map((pl) => pl.loader.request(state.positions[pl.axis])));

// A live volume's three planes in one request (/api/planes: one snapshot, one round trip): while
// a stream runs, much of the page's cost is per request. A plane whose position moved meanwhile
// is left to its own loader (movePlane asked it), so a scroll is never undone by an older answer.
async function fetchAllPlanes() {
  const pos = planes.map((pl) => state.positions[pl.axis]), defs = planes.map((pl) => pl.def);
  const sizes = defs.map((d) => d.width * d.height), starts = [0, sizes[0], sizes[0] + sizes[1]];
  const total = starts[2] + sizes[2];
  const url = `/api/planes?pos=${pos.join(',')}&layer=`;
  const wantLabels = !!(scene.labels && state.showLabels);
  const [vol, lab] = await Promise.all([
    labelsOnly ? null : fetchF32(url + 'volume'),
    wantLabels ? fetchF32(url + 'labels') : null]);
  // A growing grid that changed in flight: nothing to draw; the next poll brings the new scene.
  if ((vol && vol.length !== total) || (lab && lab.length !== total)) return null;
  const part = (a, k) => a && a.subarray(starts[k], starts[k] + sizes[k]);
  return planes.map((pl, k) => ({def: defs[k], pos: pos[k], vol: part(vol, k), lab: part(lab, k)}));
}
function applyAllPlanes(results, key, t0) {
  if (!results) return;
  planes.forEach((pl, k) => {
    if (!pl.loader.busy && results[k].pos === state.positions[pl.axis]) applyPlane(pl, results[k], t0);
  });
}
const allPlanes = new Latest('planes', fetchAllPlanes, applyAllPlanes);
const refreshLivePlanes = () => planes.every((pl) => pl.def) ? allPlanes.request(null) : refreshPlanes();
const planesSettled = () => Promise.all(planes.map((pl) => pl.loader.settled()));

// World point of plane pixel (i, j) (pixel centres at integers).
function planePixelToWorld(pl, i, j) {
  const d = pl.def, s = d.spacing, w = add(add(d.origin, mul(d.u, s * i)), mul(d.v, s * j));
  w[pl.axis] += state.positions[pl.axis];
  return w;
}
function eventToPixel(pl, e) {
  const r = pl.stage.getBoundingClientRect();
  return [(e.clientX - r.left) / r.width * pl.def.width - 0.5, (e.clientY - r.top) / r.height * pl.def.height - 0.5];
}
function crosshairTo(pl, e) {
  const [i, j] = eventToPixel(pl, e), w = planePixelToWorld(pl, i, j);
  for (const other of planes) if (other !== pl && other.def) quiet(movePlane(other.axis, w[other.axis]));
}

// ---- overlay: crosshair, title, orientation letters (on its own canvas: plane pixels stay pure)
function orientationLetter(d) {
  const a = [0, 1, 2].reduce((best, k) => (Math.abs(d[k]) > Math.abs(d[best]) ? k : best), 0);
  return [['R', 'L'], ['A', 'P'], ['I', 'S']][a][d[a] > 0 ? 1 : 0];  // LPS: +x L, +y P, +z S
}

function drawOverlays() { for (const pl of planes) drawOverlay(pl); }

function drawOverlay(pl) {
  const ctx = pl.octx, dpr = window.devicePixelRatio || 1;
  ctx.setTransform(1, 0, 0, 1, 0, 0);
  ctx.clearRect(0, 0, pl.overlay.width, pl.overlay.height);
  if (!pl.def) return;
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  const d = pl.def, r = pl.rect, W = d.width, H = d.height;
  const toX = (i) => r.x + (i + 0.5) / W * r.w, toY = (j) => r.y + (j + 0.5) / H * r.h;

  // Crosshair: where each other plane cuts this one. Line in pixel coordinates:
  // s*(i*u[b] + j*v[b]) = pos_b - origin[b].
  ctx.save();
  ctx.beginPath();
  ctx.rect(r.x, r.y, r.w, r.h);
  ctx.clip();
  ctx.lineWidth = 1;
  for (const other of planes) {
    if (other === pl || !other.def) continue;
    const b = other.axis, a = d.spacing * d.u[b], c = d.spacing * d.v[b], rhs = state.positions[b] - d.origin[b];
    let p0, p1;
    if (Math.abs(a) >= Math.abs(c)) {
      if (!a) continue;
      p0 = [(rhs - c * -0.5) / a, -0.5];
      p1 = [(rhs - c * (H - 0.5)) / a, H - 0.5];
    } else {
      p0 = [-0.5, (rhs - a * -0.5) / c];
      p1 = [W - 0.5, (rhs - a * (W - 0.5)) / c];
    }
    ctx.strokeStyle = AXIS_COLORS[b];
    ctx.globalAlpha = 0.85;
    ctx.beginPath();
    ctx.moveTo(toX(p0[0]), toY(p0[1]));
    ctx.lineTo(toX(p1[0]), toY(p1[1]));
    ctx.stroke();
  }
  ctx.restore();

  ctx.font = '12px system-ui, sans-serif';
  ctx.fillStyle = AXIS_COLORS[pl.axis];
  ctx.textAlign = 'left';
  ctx.textBaseline = 'top';
  ctx.fillText(`${d.name}  ${'xyz'[pl.axis]} = ${state.positions[pl.axis].toFixed(1)} mm`, 6, 3);

  ctx.fillStyle = '#f0f0f0';
  ctx.font = 'bold 12px system-ui, sans-serif';
  const m = 4, cx = r.x + r.w / 2, cy = r.y + r.h / 2;
  const letter = (text, x, y, align, base) => { ctx.textAlign = align; ctx.textBaseline = base; ctx.fillText(text, x, y); };
  letter(orientationLetter(mul(d.u, -1)), r.x + m, cy, 'left', 'middle');
  letter(orientationLetter(d.u), r.x + r.w - m, cy, 'right', 'middle');
  letter(orientationLetter(mul(d.v, -1)), cx, r.y + m, 'center', 'top');
  letter(orientationLetter(d.v), cx, r.y + r.h - m, 'center', 'bottom');
}

// =================================================================================== image panel

const image = {
  canvas: $('image'), ctx: null, panel: $('panel-image'), stage: null, note: null,
  W: 0, H: 0, data: null, img: null, rgba: null, pixToWorld: null, aspect: 1,
  tex: null, texDirty: false, caption: '',
};
image.ctx = image.canvas.getContext('2d', {willReadFrequently: true});
image.stage = image.panel.querySelector('.stage');
image.note = image.panel.querySelector('.note');
image.loader = new Latest('image', fetchImage, applyImageResult);

async function fetchImage(key) {
  const pr = scene.probe;
  const url = key.matrix ? `/api/image?matrix=${key.matrix.join(',')}` : `/api/image?pose=${key.pose}`;
  return {data: await fetchF32(url, pr.width * pr.height), matrix: key.matrix || poseMatrix(key.pose)};
}

function applyImageResult(res, key, t0) {
  const pr = scene.probe;
  showImage(res.data, pr.width, pr.height, rmMul(res.matrix, pr.pixel_to_probe),
    key.matrix ? `pose ${state.pose} (moved)` : `pose ${key.pose} / ${poseCount() - 1}`);
  pushStat(stats.imageMs, now() - t0);
}

// Show an image (pose image or live frame): panel pixels, and the texture for the fan in 3D.
// pixToWorld maps pixel (u, v, 0, 1) to world (row-major).
function showImage(data, W, H, pixToWorld, caption) {
  const resized = W !== image.W || H !== image.H || !image.img;
  if (resized) {
    image.W = W;
    image.H = H;
    image.canvas.width = W;
    image.canvas.height = H;
    image.img = image.ctx.createImageData(W, H);
    image.rgba = new Uint8Array(W * H * 4);
  }
  image.data = data;
  image.pixToWorld = pixToWorld;
  const sx = Math.abs(scene.probe && W === scene.probe.width ? scene.probe.pixel_to_probe[0] : 0) || rmColumnNorm(pixToWorld, 0) || 1;
  const sy = Math.abs(scene.probe && H === scene.probe.height ? scene.probe.pixel_to_probe[5] : 0) || rmColumnNorm(pixToWorld, 1) || 1;
  const aspect = (W * sx) / (H * sy), relayout = resized || aspect !== image.aspect || image.stage.hidden;
  image.aspect = aspect;
  image.caption = caption;
  setText($('image-caption'), caption);
  if (!image.note.hidden) image.note.hidden = true;
  if (image.stage.hidden) image.stage.hidden = false;
  // Laid out again only when the shape changed (a resize lays out through queueLayout): reading
  // the panel's size forces the browser's layout, which a live stream would pay every frame.
  if (relayout) layoutImage();
  drawImage();
}

function drawImage() {
  if (!image.data) return;
  windowInto(image.img.data, image.data, state.imageWindow[0], state.imageWindow[1]);
  image.ctx.putImageData(image.img, 0, 0);
  image.texDirty = true;  // the 3D view's texture is made when it next draws (imageTexturePixels)
  markDirty();
}

// Texture for the fan: the panel's pixels, alpha 0 outside the mask so only the fan shows in 3D.
function imageTexturePixels() {
  const rgba = image.rgba, n = image.W * image.H;
  rgba.set(image.img.data);
  if (mask && mask.length === n) for (let i = 0; i < n; i++) rgba[4 * i + 3] = mask[i] ? 255 : 0;
  return rgba;
}

function requestPose(k) {
  if (!hasPoses()) return Promise.resolve();
  state.pose = clamp(Math.round(Number(k)) || 0, 0, poseCount() - 1);
  probeOverride = null;  // choosing a pose resets a hand-moved probe
  $('pose-slider').value = state.pose;
  $('pose-number').value = state.pose;
  markDirty();
  return hasPoseImages() ? image.loader.request({pose: state.pose}) : Promise.resolve();
}
const stepPose = (dk) => { if (hasPoses()) quiet(requestPose(state.pose + dk)); };

// The probe moved by hand: new outline at once, the image at that pose when it lands.
function moveProbe(m) {
  probeOverride = m;
  markDirty();
  if (hasPoseImages()) quiet(image.loader.request({matrix: m.slice()}));
}

// ==================================================================================== 3-D scene

let G = null;         // WebGL2 resources; null when WebGL2 is unavailable
let dirty3d = false;

const VS_FLAT = `#version 300 es
layout(location = 0) in vec3 aPos;
uniform mat4 uVP;
void main() { gl_Position = uVP * vec4(aPos, 1.0); }`;
const FS_FLAT = `#version 300 es
precision highp float;
uniform vec3 uColor;
out vec4 oColor;
void main() { oColor = vec4(uColor, 1.0); }`;
const VS_TEX = `#version 300 es
layout(location = 0) in vec3 aPos;
layout(location = 1) in vec2 aUV;
uniform mat4 uVP;
out vec2 vUV;
void main() { vUV = aUV; gl_Position = uVP * vec4(aPos, 1.0); }`;
const FS_TEX = `#version 300 es
precision highp float;
uniform sampler2D uTex;
in vec2 vUV;
out vec4 oColor;
void main() {
  vec4 c = texture(uTex, vUV);
  if (c.a < 0.5) discard;  // outside the fan
  oColor = vec4(c.rgb, 1.0);
}`;
const VS_MESH = `#version 300 es
layout(location = 0) in vec3 aPos;
layout(location = 1) in vec3 aNrm;
uniform mat4 uVP;
out vec3 vN;
void main() { vN = aNrm; gl_Position = uVP * vec4(aPos, 1.0); }`;
const FS_MESH = `#version 300 es
precision highp float;
uniform vec3 uColor;
uniform vec3 uLight;
in vec3 vN;
out vec4 oColor;
void main() {
  float d = abs(dot(normalize(vN), uLight));  // two-sided Lambert, headlight
  oColor = vec4(uColor * (0.25 + 0.75 * d), 1.0);
}`;

const COLOR_BOX = [200 / 255, 200 / 255, 200 / 255];
const COLOR_POSE = [80 / 255, 150 / 255, 255 / 255];
const COLOR_SELECTED = [255 / 255, 230 / 255, 0];

function init3d() {
  const canvas = $('scene3d'), note = $('panel-3d').querySelector('.note');
  let gl = null;
  try { gl = canvas.getContext('webgl2', {antialias: false, preserveDrawingBuffer: true}); } catch (e) { gl = null; }
  if (!gl) {
    note.textContent = '3D view unavailable: this browser has no WebGL2.';
    note.hidden = false;
    view.webgl = false;
    hide3dControls();
    return;
  }
  try {
    G = {
      gl, canvas,
      flat: program(gl, VS_FLAT, FS_FLAT, ['uVP', 'uColor']),
      tex: program(gl, VS_TEX, FS_TEX, ['uVP', 'uTex']),
      mesh: program(gl, VS_MESH, FS_MESH, ['uVP', 'uColor', 'uLight']),
      vao: gl.createVertexArray(),
      dynPos: gl.createBuffer(),
      quadUV: gl.createBuffer(),
      poseBuf: gl.createBuffer(), poseCount: 0, posePoints: 0,
    };
    gl.bindVertexArray(G.vao);
    gl.bindBuffer(gl.ARRAY_BUFFER, G.quadUV);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([0, 0, 1, 0, 1, 1, 0, 1]), gl.STATIC_DRAW);
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
    for (const pl of planes) pl.tex = makeTexture(gl);
    image.tex = makeTexture(gl);
    view.webgl = true;
  } catch (e) {
    G = null;
    view.webgl = false;
    note.textContent = `3D view unavailable: ${e.message}`;
    note.hidden = false;
    hide3dControls();
  }
}
function hide3dControls() {
  $('panel-3d').querySelector('.hint').hidden = true;
  $('move-probe').parentElement.hidden = true;
}

function program(gl, vs, fs, uniforms) {
  const compile = (type, src) => {
    const sh = gl.createShader(type);
    gl.shaderSource(sh, src);
    gl.compileShader(sh);
    if (!gl.getShaderParameter(sh, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(sh));
    return sh;
  };
  const p = gl.createProgram();
  gl.attachShader(p, compile(gl.VERTEX_SHADER, vs));
  gl.attachShader(p, compile(gl.FRAGMENT_SHADER, fs));
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(p));
  const u = {};
  for (const name of uniforms) u[name] = gl.getUniformLocation(p, name);
  return {p, u};
}

function makeTexture(gl) {
  const t = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, t);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
  return t;
}
function uploadTexture(t, W, H, rgba) {
  const gl = G.gl;
  gl.bindTexture(gl.TEXTURE_2D, t);
  // Row 0 of the image goes to t = 0, matching the quads' texture coordinates.
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, W, H, 0, gl.RGBA, gl.UNSIGNED_BYTE,
    new Uint8Array(rgba.buffer, rgba.byteOffset, W * H * 4));
}

// Static GPU data: all pose outlines in one buffer (drawn one LINE_LOOP per pose), meshes.
function uploadPoseOutlines() {
  if (!G) return;
  const gl = G.gl, pr = scene && scene.probe;
  G.poseCount = 0;
  if (!pr || !hasPoses() || !pr.outline || !pr.outline.length) return;
  const n = pr.outline.length, N = poseCount(), out = new Float32Array(N * n * 3);
  for (let k = 0, o = 0; k < N; k++) {
    const m = poses.subarray(16 * k, 16 * k + 16);
    for (const [x, y] of pr.outline) { const w = rmApply(m, x, y, 0); out[o++] = w[0]; out[o++] = w[1]; out[o++] = w[2]; }
  }
  gl.bindBuffer(gl.ARRAY_BUFFER, G.poseBuf);
  gl.bufferData(gl.ARRAY_BUFFER, out, gl.STATIC_DRAW);
  G.poseCount = N;
  G.posePoints = n;
}
function uploadMesh(m) {
  if (!G) return;
  const gl = G.gl;
  m.gl = {pos: gl.createBuffer(), nrm: gl.createBuffer(), idx: gl.createBuffer()};
  gl.bindBuffer(gl.ARRAY_BUFFER, m.gl.pos);
  gl.bufferData(gl.ARRAY_BUFFER, m.pos, gl.STATIC_DRAW);
  gl.bindBuffer(gl.ARRAY_BUFFER, m.gl.nrm);
  gl.bufferData(gl.ARRAY_BUFFER, m.nrm, gl.STATIC_DRAW);
  gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, m.gl.idx);
  gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, m.idx, gl.STATIC_DRAW);
}

function attrib(loc, buffer, size) {
  const gl = G.gl;
  gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
  gl.enableVertexAttribArray(loc);
  gl.vertexAttribPointer(loc, size, gl.FLOAT, false, 0, 0);
}
function dynamicPoints(points) {
  const gl = G.gl, a = new Float32Array(points.length * 3);
  points.forEach((p, i) => a.set(p, 3 * i));
  gl.bindBuffer(gl.ARRAY_BUFFER, G.dynPos);
  gl.bufferData(gl.ARRAY_BUFFER, a, gl.STREAM_DRAW);
  attrib(0, G.dynPos, 3);
}
function drawFlat(vp, points, mode, color) {
  const gl = G.gl;
  gl.useProgram(G.flat.p);
  gl.uniformMatrix4fv(G.flat.u.uVP, false, vp);
  gl.uniform3fv(G.flat.u.uColor, color);
  gl.disableVertexAttribArray(1);
  dynamicPoints(points);
  gl.drawArrays(mode, 0, points.length);
}
// A textured quad; corners in the order of texture coordinates (0,0) (1,0) (1,1) (0,1).
function drawQuad(vp, tex, corners) {
  const gl = G.gl;
  gl.useProgram(G.tex.p);
  gl.uniformMatrix4fv(G.tex.u.uVP, false, vp);
  gl.activeTexture(gl.TEXTURE0);
  gl.bindTexture(gl.TEXTURE_2D, tex);
  gl.uniform1i(G.tex.u.uTex, 0);
  dynamicPoints(corners);
  attrib(1, G.quadUV, 2);
  gl.drawArrays(gl.TRIANGLE_FAN, 0, 4);
  gl.disableVertexAttribArray(1);
}
// The four pixel-edge corners of a W x H image under a pixel -> world map.
const imageCorners = (f, W, H) => [f(-0.5, -0.5), f(W - 0.5, -0.5), f(W - 0.5, H - 0.5), f(-0.5, H - 0.5)];

// Backing store = CSS size x devicePixelRatio, so one canvas pixel is one screen pixel.
function sync3dSize() {
  if (!G) return;
  const panel = $('panel-3d'), dpr = window.devicePixelRatio || 1;
  const cw = Math.max(1, Math.floor(panel.clientWidth)), ch = Math.max(1, Math.floor(panel.clientHeight));
  const c = G.canvas;
  if (c.style.width !== `${cw}px`) c.style.width = `${cw}px`;
  if (c.style.height !== `${ch}px`) c.style.height = `${ch}px`;
  const bw = Math.round(cw * dpr), bh = Math.round(ch * dpr);
  if (c.width !== bw) c.width = bw;
  if (c.height !== bh) c.height = bh;
}

function clipRange() {
  const d = len(sub(state.camera.eye, bounds.center)), R = bounds.radius;
  const near = Math.max(d - 2 * R, R * 0.002, 1e-3);
  return {near, far: Math.max(d + 2 * R, near * 10)};
}

// The view-projection matrix (column-major): perspective(fovY, canvas aspect, near, far) * lookAt.
function projection() {
  const c = state.camera, cv = G ? G.canvas : $('scene3d');
  const {near, far} = clipRange();
  return cmMul(perspective(c.fovDeg * Math.PI / 180, (cv.width / cv.height) || 1, near, far),
    lookAt(c.eye, c.target, c.up));
}

// The 3D scene is redrawn at most every RENDER_MS when something changes: software WebGL
// (headless and GPU-less machines) costs tens of milliseconds a frame, and the 2-D panels (a
// scrolled plane, a live stream's planes and counter), which are cheap, should keep their pace
// rather than wait for it. The hooks (setCamera, render3d) still draw at once.
const RENDER_MS = 100;
let last3d = 0;
function markDirty() {
  if (!G || dirty3d) return;
  dirty3d = true;
  const wait = RENDER_MS - (performance.now() - last3d);
  const draw = () => requestAnimationFrame(() => { if (dirty3d) render3d(); });
  if (wait > 0) setTimeout(draw, wait); else draw();
}

function render3d() {
  dirty3d = false;
  last3d = performance.now();
  if (!G) return;
  const gl = G.gl;
  sync3dSize();
  const vp = new Float32Array(projection());
  gl.bindVertexArray(G.vao);
  gl.viewport(0, 0, G.canvas.width, G.canvas.height);
  gl.clearColor(0.04, 0.043, 0.05, 1);
  gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  gl.disable(gl.BLEND);  // outline colours must land exactly as given
  gl.enable(gl.DEPTH_TEST);
  gl.depthFunc(gl.LEQUAL);

  // Meshes: Lambert with a headlight.
  if (meshes.length) {
    gl.useProgram(G.mesh.p);
    gl.uniformMatrix4fv(G.mesh.u.uVP, false, vp);
    gl.uniform3fv(G.mesh.u.uLight, normalize(sub(state.camera.eye, state.camera.target)));
    for (const m of meshes) {
      if (!m.gl) continue;
      gl.uniform3fv(G.mesh.u.uColor, m.color.map((c) => c / 255));
      attrib(0, m.gl.pos, 3);
      attrib(1, m.gl.nrm, 3);
      gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, m.gl.idx);
      gl.drawElements(gl.TRIANGLES, m.idx.length, gl.UNSIGNED_INT, 0);
    }
    gl.disableVertexAttribArray(1);
  }

  // The three planes, textured with their canvas pixels, at the position those pixels are from.
  for (const pl of planes) {
    if (!pl.def || pl.drawnPos == null || !pl.img) continue;
    if (pl.texDirty) { uploadTexture(pl.tex, pl.def.width, pl.def.height, pl.img.data); pl.texDirty = false; }
    const d = pl.def, s = d.spacing;
    const f = (i, j) => {
      const w = add(add(d.origin, mul(d.u, s * i)), mul(d.v, s * j));
      w[pl.axis] += pl.drawnPos;
      return w;
    };
    drawQuad(vp, pl.tex, imageCorners(f, d.width, d.height));
  }

  // Volume box: 12 edges between corners that differ in one index bit (i fastest).
  if (scene && scene.volume && scene.volume.corners) {
    const c = scene.volume.corners, pts = [];
    for (let a = 0; a < 8; a++) for (const bit of [1, 2, 4]) if (!(a & bit)) pts.push(c[a], c[a | bit]);
    drawFlat(vp, pts, gl.LINES, COLOR_BOX);
  }

  // Every pose's outline.
  if (G.poseCount) {
    gl.useProgram(G.flat.p);
    gl.uniformMatrix4fv(G.flat.u.uVP, false, vp);
    gl.uniform3fv(G.flat.u.uColor, COLOR_POSE);
    attrib(0, G.poseBuf, 3);
    for (let k = 0; k < G.poseCount; k++) gl.drawArrays(gl.LINE_LOOP, k * G.posePoints, G.posePoints);
  }

  // The shown image (pose image or live frame) in place; alpha from the mask keeps only the fan.
  if (image.data && image.pixToWorld) {
    if (image.texDirty) { uploadTexture(image.tex, image.W, image.H, imageTexturePixels()); image.texDirty = false; }
    const m = image.pixToWorld;
    drawQuad(vp, image.tex, imageCorners((u, v) => rmApply(m, u, v, 0), image.W, image.H));
  }

  // Last, always visible: the selected pose's outline, or the live frame's rectangle.
  gl.disable(gl.DEPTH_TEST);
  const sel = selectedMatrix();
  if (sel && scene.probe && scene.probe.outline && scene.probe.outline.length) {
    drawFlat(vp, scene.probe.outline.map(([x, y]) => rmApply(sel, x, y, 0)), gl.LINE_LOOP, COLOR_SELECTED);
  }
  if (live.frame && live.frame.matrix) {
    const m = live.frame.matrix;
    drawFlat(vp, imageCorners((u, v) => rmApply(m, u, v, 0), live.frame.width, live.frame.height), gl.LINE_LOOP, COLOR_SELECTED);
  }
  gl.enable(gl.DEPTH_TEST);
}

// ---- camera
function computeBounds() {
  const pts = [];
  const budget = (n) => Math.max(1, Math.floor(n / 50000));  // sample big point sets
  if (scene.volume && scene.volume.corners) pts.push(...scene.volume.corners);
  if (hasPoses() && scene.probe && scene.probe.outline) {
    const N = poseCount(), ol = scene.probe.outline, step = budget(N * ol.length);
    for (let k = 0; k < N; k++) {
      const m = poses.subarray(16 * k, 16 * k + 16);
      for (let i = 0; i < ol.length; i += step) pts.push(rmApply(m, ol[i][0], ol[i][1], 0));
    }
  }
  for (const m of meshes) {
    const n = m.pos.length / 3, step = budget(n);
    for (let i = 0; i < n; i += step) pts.push([m.pos[3 * i], m.pos[3 * i + 1], m.pos[3 * i + 2]]);
  }
  const centreCount = pts.length;  // the planes below widen the view but do not move its centre
  for (const pl of planes) {
    const d = pl.def;
    if (!d) continue;
    for (const pos of [d.min, d.max]) {
      pts.push(...imageCorners((i, j) => {
        const w = add(add(d.origin, mul(d.u, d.spacing * i)), mul(d.v, d.spacing * j));
        w[pl.axis] += pos;
        return w;
      }, d.width, d.height));
    }
  }
  if (!pts.length && live.frame) {
    const f = live.frame;
    pts.push(...imageCorners((u, v) => rmApply(f.matrix, u, v, 0), f.width, f.height));
  }
  if (!pts.length) { bounds = {center: [0, 0, 0], radius: 100}; return; }
  let center;
  if (scene.volume && scene.volume.corners) {
    center = mul(scene.volume.corners.reduce((s, p) => add(s, p), [0, 0, 0]), 1 / 8);
  } else {
    const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
    const own = centreCount ? pts.slice(0, centreCount) : pts;
    for (const p of own) for (let a = 0; a < 3; a++) { lo[a] = Math.min(lo[a], p[a]); hi[a] = Math.max(hi[a], p[a]); }
    center = mul(add(lo, hi), 0.5);
  }
  let radius = 1e-3;
  for (const p of pts) radius = Math.max(radius, len(sub(p, center)));
  bounds = {center, radius};
}

// From anterior-left-superior (LPS: +x left, -y anterior, +z superior), far enough for everything.
function initCamera() {
  const fovDeg = 30, half = fovDeg * Math.PI / 360;
  const cv = G ? G.canvas : null, aspect = cv && cv.height ? cv.width / cv.height : 1.6;
  const halfMin = Math.min(half, Math.atan(Math.tan(half) * aspect));
  const dist = bounds.radius / Math.sin(halfMin) * 1.05;
  const dir = normalize([1, -1.2, 0.8]);
  Object.assign(state.camera, {eye: add(bounds.center, mul(dir, dist)), target: bounds.center.slice(), up: [0, 0, 1], fovDeg});
}

function cameraBasis() {
  const c = state.camera, f = normalize(sub(c.target, c.eye)), right = normalize(cross(f, c.up));
  return {f, right, up: cross(right, f), dist: len(sub(c.eye, c.target))};
}
// World length of one CSS pixel at depth `depth` in front of the camera.
function pixelSize(depth) {
  const h = G ? G.canvas.clientHeight : 1;
  return 2 * depth * Math.tan(state.camera.fovDeg * Math.PI / 360) / Math.max(1, h);
}

function orbit(dx, dy) {
  const c = state.camera, up = normalize(c.up);
  let off = rotateAbout(sub(c.eye, c.target), up, -dx * 0.008);
  const right = normalize(cross(mul(off, -1), up));
  const pitched = rotateAbout(off, right, -dy * 0.008);
  if (Math.abs(dot(normalize(pitched), up)) < 0.995) off = pitched;  // stop short of the poles
  c.eye = add(c.target, off);
}
function pan(dx, dy) {
  const c = state.camera, b = cameraBasis(), k = pixelSize(b.dist);
  const delta = add(mul(b.right, -dx * k), mul(b.up, dy * k));
  c.eye = add(c.eye, delta);
  c.target = add(c.target, delta);
}
function zoom(deltaY) {
  const c = state.camera, f = clamp(Math.exp(deltaY * 0.0015), 0.5, 2);
  c.eye = add(c.target, mul(sub(c.eye, c.target), f));
}
function dragProbe(dx, dy) {
  const m = selectedMatrix().slice(), b = cameraBasis();
  const depth = Math.max(1e-3, dot(sub([m[3], m[7], m[11]], state.camera.eye), b.f)), k = pixelSize(depth);
  const delta = add(mul(b.right, dx * k), mul(b.up, -dy * k));
  m[3] += delta[0]; m[7] += delta[1]; m[11] += delta[2];
  moveProbe(m);
}
// Tilt about the probe's lateral axis (column 0) through its origin: T' = T * Rx(angle).
function tiltProbe(deg) {
  const m = selectedMatrix().slice(), a = deg * Math.PI / 180, c = Math.cos(a), s = Math.sin(a);
  for (let r = 0; r < 3; r++) {
    const y = m[4 * r + 1], z = m[4 * r + 2];
    m[4 * r + 1] = c * y + s * z;
    m[4 * r + 2] = -s * y + c * z;
  }
  moveProbe(m);
}
const canMoveProbe = () => hasPoses();

// ======================================================================================= layout

// Fit a w:h = aspect box into the panel area below the title row, centred.
function fitStage(panel, stage, aspect, top) {
  const cw = panel.clientWidth, ch = panel.clientHeight, m = 4;
  const aw = Math.max(1, cw - 2 * m), ah = Math.max(1, ch - top - m);
  let w = aw, h = aw / aspect;
  if (h > ah) { h = ah; w = ah * aspect; }
  w = Math.max(1, Math.floor(w));
  h = Math.max(1, Math.floor(h));
  const x = Math.floor((cw - w) / 2), y = Math.floor(top + (ah - h) / 2);
  Object.assign(stage.style, {left: `${x}px`, top: `${y}px`, width: `${w}px`, height: `${h}px`});
  return {x, y, w, h};
}

function layoutPlane(pl) {
  const dpr = window.devicePixelRatio || 1, cw = pl.panel.clientWidth, ch = pl.panel.clientHeight;
  const bw = Math.max(1, Math.round(cw * dpr)), bh = Math.max(1, Math.round(ch * dpr));
  if (pl.overlay.width !== bw) pl.overlay.width = bw;
  if (pl.overlay.height !== bh) pl.overlay.height = bh;
  pl.overlay.style.width = `${cw}px`;
  pl.overlay.style.height = `${ch}px`;
  if (pl.def) pl.rect = fitStage(pl.panel, pl.stage, pl.def.width / pl.def.height, 20);
  drawOverlay(pl);
}
function layoutImage() {
  if (image.W) fitStage(image.panel, image.stage, image.aspect, 20);
}
function layoutAll() {
  for (const pl of planes) layoutPlane(pl);
  layoutImage();
  if (G) render3d();
}
let layoutQueued = false;
function queueLayout() {  // coalesced into one animation frame (also avoids ResizeObserver loops)
  if (layoutQueued) return;
  layoutQueued = true;
  requestAnimationFrame(() => { layoutQueued = false; layoutAll(); });
}

// ============================================================================== toolbar & scene

function fmt(x) { return Number.isFinite(x) ? String(Math.round(x * 1e6) / 1e6) : ''; }

function updateWindowUi() {
  const [L, W] = state.window;
  $('level').value = fmt(L);
  $('width').value = fmt(W);
  const presets = (scene && scene.volume && scene.volume.presets) || [];
  const i = presets.findIndex((p) => p[1] === L && p[2] === W);
  $('preset').value = i >= 0 ? String(i) : 'custom';
}
function updateImageWindowUi() {
  $('img-level').value = fmt(state.imageWindow[0]);
  $('img-width').value = fmt(state.imageWindow[1]);
}

// Install a (new) scene. Used at start and, in live mode, whenever the grid changed.
function applyScene(sc) {
  const prev = scene;
  scene = sc;
  view.scene = sc;
  const title = sc.title || 'sonoslice view';
  $('title').textContent = title;
  $('title').title = title;
  document.title = `${title} — sonoslice view`;

  labelsOnly = !sc.volume && !!sc.labels;
  if (sc.volume) {
    if (!prev || !prev.volume) state.window = sc.volume.window.slice();
    const sel = $('preset');
    sel.replaceChildren(...(sc.volume.presets || []).map((p, i) => new Option(`${p[0]} (${fmt(p[1])}/${fmt(p[2])})`, String(i))));
    sel.append(new Option('custom', 'custom'));
  }
  $('window-group').hidden = !sc.volume;
  if (!prev) state.showLabels = labelsOnly;  // labels start off when there is a volume
  if (labelsOnly) state.showLabels = true;
  $('labels-group').hidden = !sc.labels;
  $('labels').checked = state.showLabels;
  $('labels').disabled = labelsOnly;
  updateWindowUi();

  const defs = sc.planes || [];
  for (const pl of planes) setupPlane(pl, defs.find((d) => d.axis === pl.axis), !!prev);

  if (!prev) state.imageWindow = (sc.image_window || [0.5, 1]).slice();
  updateImageWindowUi();
  $('live-stats').hidden = !sc.live;
  updateImagePlaceholder();
}

function updatePoseUi() {
  const n = poseCount();
  $('pose-group').hidden = n === 0;
  for (const id of ['pose-slider', 'pose-number']) {
    $(id).max = String(Math.max(0, n - 1));
    $(id).value = String(state.pose);
  }
  $('pose-count').textContent = `/ ${Math.max(0, n - 1)}`;
  $('image-window-group').hidden = !(hasPoseImages() || (scene && scene.live));
}

function updateImagePlaceholder() {
  if (image.data) return;
  image.note.hidden = false;
  image.stage.hidden = true;
  image.note.textContent = scene.live ? 'waiting for the first frame…'
    : !scene.probe ? 'no probe' : !scene.image_source ? 'no image source' : 'no poses';
}

// Poses, mask and meshes: fetched when the scene names them and they are not loaded yet.
async function loadSceneData() {
  const jobs = [];
  const wantPoses = scene.poses ? scene.poses.count : 0;
  if (wantPoses !== poseCount()) {
    jobs.push(wantPoses > 0
      ? fetchF32(scene.poses.url, wantPoses * 16).then((p) => { poses = p; })
      : Promise.resolve().then(() => { poses = null; }));
  }
  const pr = scene.probe;
  if (pr && (!mask || mask.length !== pr.width * pr.height)) {
    jobs.push(fetchOk('/api/mask').then((r) => r.arrayBuffer()).then((b) => {
      const mk = new Uint8Array(b);
      if (mk.length !== pr.width * pr.height) throw new Error(`/api/mask: expected ${pr.width * pr.height} bytes, got ${mk.length}`);
      mask = mk;
    }));
  }
  const urls = (scene.meshes || []).map((m) => m.url).join('|');
  if (urls !== meshes.map((m) => m.url).join('|')) {
    jobs.push(Promise.all((scene.meshes || []).map(loadMesh)).then((ms) => { meshes = ms; }));
  }
  await Promise.all(jobs);
  if (state.pose >= poseCount()) state.pose = 0;
  updatePoseUi();
  uploadPoseOutlines();
}

async function loadMesh(info) {
  const buf = await (await fetchOk(info.url)).arrayBuffer();
  const dv = new DataView(buf);
  const nv = dv.getUint32(0, true), nt = dv.getUint32(4, true);
  if (buf.byteLength !== 8 + 12 * nv + 12 * nt) throw new Error(`${info.url}: size does not match ${nv} vertices, ${nt} triangles`);
  const pos = new Float32Array(buf, 8, 3 * nv), idx = new Uint32Array(buf, 8 + 12 * nv, 3 * nt);
  // Vertex normals: area-weighted sum of the faces' normals.
  const nrm = new Float32Array(3 * nv);
  for (let t = 0; t < 3 * nt; t += 3) {
    const a = 3 * idx[t], b = 3 * idx[t + 1], c = 3 * idx[t + 2];
    if (a >= 3 * nv || b >= 3 * nv || c >= 3 * nv) throw new Error(`${info.url}: index out of range`);
    const e1 = [pos[b] - pos[a], pos[b + 1] - pos[a + 1], pos[b + 2] - pos[a + 2]];
    const e2 = [pos[c] - pos[a], pos[c + 1] - pos[a + 1], pos[c + 2] - pos[a + 2]];
    const n = cross(e1, e2);
    for (const v of [a, b, c]) { nrm[v] += n[0]; nrm[v + 1] += n[1]; nrm[v + 2] += n[2]; }
  }
  for (let v = 0; v < 3 * nv; v += 3) {
    const l = Math.hypot(nrm[v], nrm[v + 1], nrm[v + 2]);
    if (l > 0) { nrm[v] /= l; nrm[v + 1] /= l; nrm[v + 2] /= l; } else { nrm[v + 2] = 1; }
  }
  const m = {name: info.name, url: info.url, color: info.color || [200, 200, 200], pos, nrm, idx, gl: null};
  uploadMesh(m);
  return m;
}

// ========================================================================================= live

// Polled every 25 ms: only a text that changed is written (each write costs the browser a layout).
function updateLiveBox(st) {
  const show = (id, v) => setText($(id), v == null ? '–' : String(v));
  show('live-received', st.received);
  show('live-compounded', st.compounded);
  show('live-dropped', st.dropped);
  show('live-rejected', st.rejected);
  const lat = st.latency_ms || {};
  const ms = (x) => (Number.isFinite(x) ? x.toFixed(1) : '–');
  setText($('live-latency'), `${ms(lat.p50)}/${ms(lat.p95)}/${ms(lat.p99)}`);
  const count = scene && scene.mode === 'live-probe' ? st.images : st.compounded;
  setText($('frame-counter'), String(count == null ? 0 : count));
  setText($('live-state'), st.running === false ? 'live (stopped)' : 'live');
  live.running = st.running !== false;
}

async function fetchLiveFrame(frame) {
  const r = await fetchOk('/api/live/frame');
  const bytes = await r.arrayBuffer();
  const data = r.headers.get('X-Pixel-Type') === 'uint8' ? new Uint8Array(bytes) : new Float32Array(bytes);
  if (data.length !== frame.width * frame.height) return;  // a newer frame of another size: next poll
  // If the server already has a newer frame than the one polled, the next poll brings its matrix.
  live.seq = frame.seq;
  live.frame = frame;
  showImage(data, frame.width, frame.height, frame.matrix, `live frame ${r.headers.get('X-Frame-Seq') || frame.seq}`);
  stats.framesShown++;
  if (!cameraTouched && !scene.volume && !hasPoses() && !meshes.length) { computeBounds(); initCamera(); }
}

async function handleLive(st) {
  updateLiveBox(st);
  let sceneChanged = false;
  if (st.scene_version !== live.sceneVer) {
    const sc = await fetchJSON('/api/scene');
    live.sceneVer = st.scene_version;
    applyScene(sc);
    await loadSceneData();
    computeBounds();
    if (!cameraTouched) initCamera();
    queueLayout();
    showSummary();
    sceneChanged = true;
  }
  const volumeChanged = st.volume_version !== live.volVer;
  // The newest frame travels on its own (one request at a time), so that a large frame never
  // holds back the planes' next update.
  if (st.frame && st.frame.seq !== live.seq && !live.frameInFlight) {
    live.frameInFlight = true;
    fetchLiveFrame(st.frame)
      .catch((e) => reportError('live frame', e))
      .finally(() => { live.frameInFlight = false; });
  }
  // The planes of a new volume also travel on their own, so polling goes on while they load; a
  // version that arrives meanwhile is fetched by a later poll (live.volVer moves only when drawn).
  if ((volumeChanged || sceneChanged) && !live.planesInFlight) {
    live.planesInFlight = true;
    const version = st.volume_version;
    refreshLivePlanes()
      .then(() => {
        live.volVer = version;
        if (planes.some((pl) => pl.def)) stats.liveUpdates++;
        markDirty();
      })
      .catch((e) => reportError('live planes', e))
      .finally(() => { live.planesInFlight = false; });
  }
}

// One poll at a time (setTimeout chain); slower once the run has stopped.
async function pollLive() {
  try {
    const st = await fetchJSON(scene.live.url);
    stats.polls++;
    await handleLive(st);
  } catch (e) {
    reportError('live', e);
  }
  setTimeout(pollLive, live.running ? 25 : 500);
}

// ========================================================================================= hooks

function setPose(k) {
  return requestPose(k).then(() => render3d());
}
function setPlane(axis, pos) {
  return movePlane(Number(axis), pos).then(() => render3d());
}
function setWindow(level, width) {
  level = Number(level);
  width = Number(width);
  if (!Number.isFinite(level) || !(width > 0)) {
    updateWindowUi();
    return Promise.reject(new Error('window: level must be a number and width > 0'));
  }
  state.window = [level, width];
  updateWindowUi();
  for (const pl of planes) drawPlane(pl);
  markDirty();
  return planesSettled().then(() => render3d());
}
function setImageWindow(level, width) {
  level = Number(level);
  width = Number(width);
  if (!Number.isFinite(level) || !(width > 0)) {
    updateImageWindowUi();
    return Promise.reject(new Error('image window: level must be a number and width > 0'));
  }
  state.imageWindow = [level, width];
  updateImageWindowUi();
  drawImage();
  return image.loader.settled().then(() => render3d());
}
function setLabels(on) {
  state.showLabels = labelsOnly || !!on;
  $('labels').checked = state.showLabels;
  for (const pl of planes) drawPlane(pl);  // turning off needs no fetch
  return (state.showLabels ? refreshPlanes() : planesSettled()).then(() => render3d());
}
function setCamera(cam) {
  const c = state.camera;
  for (const key of ['eye', 'target', 'up']) if (cam && cam[key]) c[key] = Array.from(cam[key], Number);
  if (cam && cam.fovDeg != null) c.fovDeg = Number(cam.fovDeg);
  cameraTouched = true;
  render3d();
}

// ====================================================================================== events

// Pointer capture keeps a drag alive outside the element; synthetic events have no pointer to capture.
function capture(el, id) {
  try { el.setPointerCapture(id); } catch (e) { /* no active pointer: the drag still works inside */ }
}

function isTyping(t) {
  return !!t && (t.tagName === 'TEXTAREA' || t.tagName === 'SELECT' || t.isContentEditable ||
    (t.tagName === 'INPUT' && t.type !== 'checkbox'));
}

function bindEvents() {
  // Toolbar.
  $('preset').addEventListener('change', (e) => {
    const p = scene.volume.presets[Number(e.target.value)];
    if (p) quiet(setWindow(p[1], p[2]));
  });
  const onWindowInput = () => quiet(setWindow($('level').value, $('width').value));
  $('level').addEventListener('change', onWindowInput);
  $('width').addEventListener('change', onWindowInput);
  const onImageWindowInput = () => quiet(setImageWindow($('img-level').value, $('img-width').value));
  $('img-level').addEventListener('change', onImageWindowInput);
  $('img-width').addEventListener('change', onImageWindowInput);
  $('labels').addEventListener('change', (e) => quiet(setLabels(e.target.checked)));
  $('pose-slider').addEventListener('input', (e) => quiet(requestPose(e.target.value)));
  $('pose-number').addEventListener('change', (e) => quiet(requestPose(e.target.value)));

  // Keyboard: poses anywhere (unless typing), planes when hovered.
  document.addEventListener('keydown', (e) => {
    if (isTyping(e.target) || e.altKey || e.ctrlKey || e.metaKey) return;
    const poseKeys = {ArrowLeft: -1, ArrowRight: 1, PageUp: 10, PageDown: -10};
    if (e.key in poseKeys) {
      if (!hasPoses()) return;
      stepPose(poseKeys[e.key]);
    } else if ((e.key === 'ArrowUp' || e.key === 'ArrowDown') && hoveredAxis != null) {
      scrollPlane(hoveredAxis, e.key === 'ArrowUp' ? 1 : -1);
    } else {
      return;
    }
    e.preventDefault();
  });

  // Planes: wheel scrolls, left button sets the crosshair, right-drag sets the window.
  for (const pl of planes) {
    const p = pl.panel;
    let drag = null;
    p.addEventListener('pointerenter', () => { hoveredAxis = pl.axis; });
    p.addEventListener('pointerleave', () => { if (hoveredAxis === pl.axis) hoveredAxis = null; });
    p.addEventListener('wheel', (e) => {
      e.preventDefault();
      if (e.deltaY) scrollPlane(pl.axis, e.deltaY < 0 ? 1 : -1);  // one step per wheel event
    }, {passive: false});
    p.addEventListener('contextmenu', (e) => e.preventDefault());
    p.addEventListener('pointerdown', (e) => {
      if (!pl.def) return;
      if (isTyping(document.activeElement)) document.activeElement.blur();  // arrows go to the planes
      if (e.button === 0) {
        drag = {mode: 'cross'};
        crosshairTo(pl, e);
      } else if (e.button === 2 && !labelsOnly) {
        drag = {mode: 'window', x: e.clientX, y: e.clientY, L: state.window[0], W: state.window[1]};
      } else {
        return;
      }
      capture(p, e.pointerId);
      e.preventDefault();
    });
    p.addEventListener('pointermove', (e) => {
      if (!drag) return;
      if (drag.mode === 'cross') {
        crosshairTo(pl, e);
      } else {
        const k = Math.max(Math.abs(drag.W), 1e-6) / 250, dx = e.clientX - drag.x, dy = e.clientY - drag.y;
        quiet(setWindow(drag.L + dy * k, Math.max(drag.W * 0.01, drag.W + dx * k)));
      }
    });
    const end = (e) => { if (drag) { drag = null; if (p.hasPointerCapture(e.pointerId)) p.releasePointerCapture(e.pointerId); } };
    p.addEventListener('pointerup', end);
    p.addEventListener('pointercancel', end);
  }

  // Image panel: the wheel steps through poses.
  image.panel.addEventListener('wheel', (e) => {
    e.preventDefault();
    if (e.deltaY && hasPoses()) stepPose(e.deltaY > 0 ? 1 : -1);
  }, {passive: false});

  // 3-D: orbit / pan / zoom, and moving the probe.
  const c3 = $('scene3d');
  let drag = null;
  c3.addEventListener('contextmenu', (e) => e.preventDefault());
  c3.addEventListener('pointerdown', (e) => {
    let mode = null;
    if (e.button === 1 || (e.button === 0 && e.shiftKey)) mode = 'pan';
    else if (e.button === 0 && (e.ctrlKey || $('move-probe').checked) && canMoveProbe()) mode = 'probe';
    else if (e.button === 0) mode = 'orbit';
    if (!mode) return;
    drag = {mode, x: e.clientX, y: e.clientY};
    capture(c3, e.pointerId);
    e.preventDefault();
  });
  c3.addEventListener('pointermove', (e) => {
    if (!drag) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag.x = e.clientX;
    drag.y = e.clientY;
    if (!dx && !dy) return;
    if (drag.mode === 'probe') {
      dragProbe(dx, dy);
    } else {
      if (drag.mode === 'pan') pan(dx, dy); else orbit(dx, dy);
      cameraTouched = true;
    }
    markDirty();
  });
  const end3 = (e) => { if (drag) { drag = null; if (c3.hasPointerCapture(e.pointerId)) c3.releasePointerCapture(e.pointerId); } };
  c3.addEventListener('pointerup', end3);
  c3.addEventListener('pointercancel', end3);
  c3.addEventListener('wheel', (e) => {
    e.preventDefault();
    if (!e.deltaY) return;
    if ((e.altKey || e.ctrlKey) && canMoveProbe()) {
      tiltProbe(e.deltaY > 0 ? 2 : -2);
    } else {
      zoom(e.deltaY);
      cameraTouched = true;
    }
    markDirty();
  }, {passive: false});

  // Layout follows the window (and devicePixelRatio changes, which fire resize).
  new ResizeObserver(queueLayout).observe($('panels'));
  window.addEventListener('resize', queueLayout);
}

// ========================================================================================= start

function showSummary() {
  const parts = [];
  if (scene.volume) parts.push(`${scene.volume.dims.join('×')} volume`);
  else if (scene.live) parts.push('no volume yet');
  if (hasPoses()) parts.push(`${poseCount()} poses`);
  if (meshes.length) parts.push(`${meshes.length} mesh${meshes.length > 1 ? 'es' : ''}`);
  if (!G) parts.push('no WebGL2');
  setStatus(`ready${parts.length ? ' — ' + parts.join(', ') : ''}`);
}

async function main() {
  init3d();
  bindEvents();
  setStatus('loading scene…');
  try {
    let sc = await fetchJSON('/api/scene');
    let liveStatus = null;
    if (sc.live) {
      // Versions first, then the scene again: the scene we use is never older than the versions
      // we compare the next polls against, so no grid change can be missed.
      liveStatus = await fetchJSON(sc.live.url);
      stats.polls++;
      sc = await fetchJSON('/api/scene');
      live.sceneVer = liveStatus.scene_version;
      live.volVer = liveStatus.volume_version;
    }
    applyScene(sc);
    if (liveStatus) updateLiveBox(liveStatus);
    await loadSceneData();
    sync3dSize();      // the initial camera's distance depends on the 3-D panel's aspect
    computeBounds();
    initCamera();
    layoutAll();

    const jobs = [refreshPlanes()];
    if (hasPoseImages()) jobs.push(requestPose(state.pose));
    if (liveStatus && liveStatus.frame) jobs.push(fetchLiveFrame(liveStatus.frame));
    await Promise.all(jobs);
    layoutAll();
    // Ready (the planes and the image on screen) before the first 3D frame, which software
    // WebGL takes a few hundred milliseconds to draw.
    view.ready = true;
    markDirty();
    showSummary();
    if (sc.live) setTimeout(pollLive, 50);
  } catch (e) {
    reportError('loading', e);
  }
}

main();

})();
