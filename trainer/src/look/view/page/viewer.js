// s3tir-train view: the page's script. It asks the server what the run holds
// (/api/scene.json: meshes, unit, palettes, the recorded camera to start from), loads the mesh
// PLY written by `s3tir-train mesh` with three.js's PLY loader (its `kelvin` vertex property),
// colours the vertices through the chosen palette and range (unlit by default, so a colour on
// screen is the colour bar's), and reads the value under the pointer: interpolated over the
// picked triangle, with the nearest vertex's stored value beside it.
//
// URL parameters (for links and tests): mesh=NAME, palette=NAME, lo=, hi=, shade=1,
// pick=X,Y (a click at X, Y in [0, 1] of the canvas, from its top left, once loaded) or
// pickat=X,Y,Z (a click where the world point appears); the result also goes into the hidden
// <output id="pick"> as data attributes.

import * as THREE from 'three';
import { OrbitControls } from '/vendor/OrbitControls.js';
import { PLYLoader } from '/vendor/PLYLoader.js';

const $ = (id) => document.getElementById(id);
const params = new URLSearchParams(location.search);
const canvas = $('view');
const bar = $('bar');

const state = {
  info: null, // scene.json
  radiometric: false,
  unit: '',
  palette: null, // { name, lut: [[r, g, b] x 256] }
  lo: 0,
  hi: 1,
  mesh: null, // THREE.Mesh
  meshInfo: null,
  start: null, // { position, target, up, fov }
  marker: null,
  pinned: null, // the clicked point
};

const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
// Vertex colours are the palette's sRGB bytes / 255, written to the screen unconverted: a
// colour on screen is the colour bar's.
renderer.outputColorSpace = THREE.LinearSRGBColorSpace;
renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
const scene = new THREE.Scene();
// slate, not black: ironbow's cold end is black
scene.background = new THREE.Color().setHex(0x3a3f47, THREE.LinearSRGBColorSpace);
scene.add(new THREE.HemisphereLight(0xffffff, 0x444444, 2.2));
const camera = new THREE.PerspectiveCamera(50, 1, 0.01, 1000);
// OrbitControls orbits about the camera's up as it is when they are made: they are made again
// whenever the up changes (goHome).
let controls = null;
function makeControls() {
  if (controls) controls.dispose();
  controls = new OrbitControls(camera, canvas);
  controls.addEventListener('change', render);
}
const raycaster = new THREE.Raycaster();

function status(text, bad = false) {
  $('status').textContent = text;
  $('status').className = bad ? 'bad' : '';
}

function fail(message) {
  status(message, true);
  document.body.dataset.error = message;
}

function render() {
  renderer.render(scene, camera);
}

function resize() {
  const stage = $('stage');
  const w = Math.max(1, stage.clientWidth);
  const h = Math.max(1, stage.clientHeight);
  renderer.setSize(w, h, false);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
  bar.height = Math.max(160, Math.min(420, h - 16));
  drawBar();
  render();
}

// --- values and units

function celsius(k) {
  return k - 273.15;
}

function describe(v) {
  if (!Number.isFinite(v)) return 'not observed';
  if (state.radiometric) return `${v.toFixed(2)} K · ${celsius(v).toFixed(2)} °C`;
  return `${v.toFixed(4)} ${state.unit}`;
}

function colourOf(v) {
  const lut = state.palette.lut;
  if (!Number.isFinite(v)) return [128, 128, 128];
  const span = state.hi - state.lo;
  const t = span > 0 ? (v - state.lo) / span : 0.5;
  const i = Math.round(Math.min(1, Math.max(0, t)) * (lut.length - 1));
  return lut[i];
}

function recolour() {
  if (!state.mesh) return;
  const kelvin = state.mesh.geometry.getAttribute('kelvin');
  const colour = state.mesh.geometry.getAttribute('color');
  for (let i = 0; i < kelvin.count; i++) {
    const c = colourOf(kelvin.getX(i));
    colour.setXYZ(i, c[0] / 255, c[1] / 255, c[2] / 255);
  }
  colour.needsUpdate = true;
  drawBar();
  render();
}

// --- the colour bar: the palette over [lo, hi] with ticks in K and °C (or the unit)

function niceTicks(lo, hi, n) {
  const span = hi - lo;
  if (!(span > 0)) return [lo];
  // the step among 1, 2, 2.5, 5 × 10^k whose tick count is nearest n
  const mag = 10 ** Math.floor(Math.log10(span / n));
  const steps = [1, 2, 2.5, 5, 10].map((m) => m * mag);
  const step = steps.reduce((a, b) => (Math.abs(span / b - n) < Math.abs(span / a - n) ? b : a));
  const ticks = [];
  // at most 50: a step below the values' float spacing would never advance
  for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9 * span && ticks.length < 50; v += step) {
    ticks.push(v);
  }
  return ticks;
}

// Decimals that write the tick step exactly (5 → 0, 2.5 → 1, 0.02 → 2).
function decimals(step) {
  let d = 0;
  while (d < 6 && Math.abs(Math.round(step * 10 ** d) - step * 10 ** d) > 1e-6) d++;
  return d;
}

function drawBar() {
  const g = bar.getContext('2d');
  const w = bar.width;
  const h = bar.height;
  g.clearRect(0, 0, w, h);
  if (!state.palette) return;
  const top = 26;
  const bottom = h - 10;
  const x = 8;
  const strip = 18;
  const lut = state.palette.lut;
  for (let y = top; y <= bottom; y++) {
    const t = 1 - (y - top) / (bottom - top);
    const c = lut[Math.round(t * (lut.length - 1))];
    g.fillStyle = `rgb(${c[0]},${c[1]},${c[2]})`;
    g.fillRect(x, y, strip, 1);
  }
  g.strokeStyle = '#e6e6e6';
  g.strokeRect(x - 0.5, top - 0.5, strip + 1, bottom - top + 1);
  g.fillStyle = '#e6e6e6';
  g.font = '12px system-ui, sans-serif';
  g.textBaseline = 'middle';
  g.fillText(state.radiometric ? 'K        °C' : state.unit, x, 12);
  const ticks = niceTicks(state.lo, state.hi, 5);
  const digits = ticks.length > 1 ? decimals(ticks[1] - ticks[0]) : 2;
  for (const v of ticks) {
    const y = bottom - ((v - state.lo) / (state.hi - state.lo)) * (bottom - top);
    g.fillRect(x + strip, Math.round(y), 5, 1);
    let label = v.toFixed(digits);
    if (state.radiometric) label += `  ${celsius(v).toFixed(Math.max(1, digits))}`;
    g.fillText(label, x + strip + 8, y);
  }
}

// --- picking

// The value at a canvas point given in [0, 1] from the top left: the hit, the triangle, the
// value interpolated over it (its observed vertices) and the nearest vertex's stored value.
function pickAt(u, v) {
  if (!state.mesh) return null;
  raycaster.setFromCamera(new THREE.Vector2(2 * u - 1, 1 - 2 * v), camera);
  const hit = raycaster.intersectObject(state.mesh, false)[0];
  if (!hit || !hit.face) return null;
  const pos = state.mesh.geometry.getAttribute('position');
  const kelvin = state.mesh.geometry.getAttribute('kelvin');
  const ids = [hit.face.a, hit.face.b, hit.face.c];
  const corners = ids.map((i) => new THREE.Vector3().fromBufferAttribute(pos, i));
  const bary = new THREE.Vector3();
  THREE.Triangle.getBarycoord(hit.point, corners[0], corners[1], corners[2], bary);
  const weights = [bary.x, bary.y, bary.z];
  let sum = 0;
  let wsum = 0;
  ids.forEach((i, k) => {
    const value = kelvin.getX(i);
    if (Number.isFinite(value)) {
      sum += weights[k] * value;
      wsum += weights[k];
    }
  });
  const nearest = ids[weights.indexOf(Math.max(...weights))];
  return {
    point: hit.point,
    face: hit.faceIndex,
    vertices: ids,
    value: wsum > 0 ? sum / wsum : NaN,
    nearest,
    nearestValue: kelvin.getX(nearest),
  };
}

function pickText(p) {
  const at = `(${p.point.x.toFixed(3)}, ${p.point.y.toFixed(3)}, ${p.point.z.toFixed(3)}) m`;
  return `${describe(p.value)} at ${at}; vertex ${p.nearest}: ${describe(p.nearestValue)}`;
}

// The readout: the point under the pointer (hover), and the pinned one (a click) below it.
// A click on the background unpins.
function showPick(p, pinned) {
  if (pinned) {
    state.pinned = p;
    state.marker.visible = Boolean(p);
    if (p) state.marker.position.copy(p.point);
    render();
  }
  const lines = [];
  if (!pinned && p) lines.push(pickText(p));
  if (state.pinned) lines.push(`pinned: ${pickText(state.pinned)}`);
  $('readout').textContent = lines.join('\n');
}

function recordPick(p) {
  const o = $('pick');
  o.dataset.hit = p ? '1' : '0';
  if (p) {
    o.dataset.value = String(p.value);
    o.dataset.point = [p.point.x, p.point.y, p.point.z].join(',');
    o.dataset.face = String(p.face);
    o.dataset.vertices = p.vertices.join(',');
    o.dataset.nearest = String(p.nearest);
    o.dataset.nearestValue = String(p.nearestValue);
  }
  o.textContent = p ? describe(p.value) : 'no surface';
}

let down = null;
let hoverTimer = 0;
function canvasUV(e) {
  const r = canvas.getBoundingClientRect();
  return [(e.clientX - r.left) / r.width, (e.clientY - r.top) / r.height];
}
canvas.addEventListener('pointerdown', (e) => {
  down = [e.clientX, e.clientY];
});
canvas.addEventListener('pointerup', (e) => {
  if (down && Math.hypot(e.clientX - down[0], e.clientY - down[1]) < 4) {
    const p = pickAt(...canvasUV(e));
    showPick(p, true);
    recordPick(p);
  }
  down = null;
});
canvas.addEventListener('pointermove', (e) => {
  if (e.buttons) return;
  clearTimeout(hoverTimer);
  const uv = canvasUV(e);
  // raycasting every triangle is a few ms: read once the pointer rests
  hoverTimer = setTimeout(() => showPick(pickAt(...uv), false), 60);
});

// --- the camera

function startView(sphere) {
  const c = state.info.camera;
  if (c) {
    const eye = new THREE.Vector3(...c.eye);
    const fwd = new THREE.Vector3(...c.forward).normalize();
    const along = Math.max(sphere.center.clone().sub(eye).dot(fwd), 0.05 * sphere.radius);
    return {
      position: eye,
      target: eye.clone().addScaledVector(fwd, along),
      up: new THREE.Vector3(...c.up),
      fov: c.fov_deg,
    };
  }
  return {
    position: sphere.center.clone().add(new THREE.Vector3(0, 0, 2.5 * sphere.radius)),
    target: sphere.center.clone(),
    up: new THREE.Vector3(0, 1, 0),
    fov: 50,
  };
}

function goHome() {
  const s = state.start;
  if (!s) return;
  camera.up.copy(s.up);
  makeControls();
  camera.position.copy(s.position);
  camera.fov = s.fov;
  controls.target.copy(s.target);
  camera.lookAt(s.target);
  camera.updateProjectionMatrix();
  controls.update();
  render();
}

// --- loading

function setRange(lo, hi) {
  state.lo = lo;
  state.hi = hi > lo ? hi : lo + 1e-6;
  const digits = state.radiometric ? 2 : 4;
  $('lo').value = state.lo.toFixed(digits);
  $('hi').value = state.hi.toFixed(digits);
}

function loadMesh(info) {
  return new Promise((resolve, reject) => {
    const loader = new PLYLoader();
    loader.setCustomPropertyNameMapping({ kelvin: ['kelvin'] });
    loader.load(
      info.url,
      resolve,
      (e) => {
        if (e.lengthComputable) status(`loading ${info.name}: ${Math.round((100 * e.loaded) / e.total)} %`);
      },
      () => reject(new Error(`${info.name} did not load`)),
    );
  });
}

async function showMesh(info) {
  status(`loading ${info.name}…`);
  const geometry = await loadMesh(info);
  if (!geometry.getAttribute('kelvin')) throw new Error(`${info.name} has no kelvin property`);
  const n = geometry.getAttribute('position').count;
  geometry.setAttribute('color', new THREE.Float32BufferAttribute(new Float32Array(3 * n), 3));
  if (!geometry.getAttribute('normal')) geometry.computeVertexNormals();
  geometry.computeBoundingSphere();
  if (state.mesh) {
    scene.remove(state.mesh);
    state.mesh.geometry.dispose();
  }
  state.mesh = new THREE.Mesh(geometry, material());
  scene.add(state.mesh);
  state.meshInfo = info;
  const sphere = geometry.boundingSphere;
  const eye = state.info.camera ? new THREE.Vector3(...state.info.camera.eye) : sphere.center;
  camera.near = Math.max(1e-4, sphere.radius * 1e-3);
  camera.far = 4 * (eye.distanceTo(sphere.center) + sphere.radius) + sphere.radius * 50;
  const marker = new THREE.Mesh(
    new THREE.SphereGeometry(sphere.radius * 0.004, 16, 8),
    new THREE.MeshBasicMaterial({ color: new THREE.Color().setHex(0x00e5ff, THREE.LinearSRGBColorSpace) }),
  );
  marker.visible = false;
  if (state.marker) scene.remove(state.marker);
  state.marker = marker;
  scene.add(marker);
  state.start = startView(sphere);
  const lo = Number.parseFloat(params.get('lo'));
  const hi = Number.parseFloat(params.get('hi'));
  // a mesh whose vertices have no value has no range: grey, shown over [0, 1]
  setRange(
    Number.isFinite(lo) ? lo : (info.lo ?? 0),
    Number.isFinite(hi) ? hi : (info.hi ?? 1),
  );
  recolour();
  goHome();
  const unseen = info.unobserved ? `, ${info.unobserved} not observed (grey)` : '';
  status(`${state.info.run} · ${info.name}: ${info.vertices} vertices, ${info.triangles} triangles${unseen}`);
}

function material() {
  const shade = $('shade').checked;
  const m = shade
    ? new THREE.MeshLambertMaterial({ vertexColors: true, side: THREE.DoubleSide })
    : new THREE.MeshBasicMaterial({ vertexColors: true, side: THREE.DoubleSide });
  return m;
}

async function main() {
  const response = await fetch('/api/scene.json');
  if (!response.ok) throw new Error(`/api/scene.json: ${response.status}`);
  const info = await response.json();
  state.info = info;
  state.radiometric = info.radiometric === true;
  state.unit = info.unit;
  document.title = `s3tir viewer: ${info.run}`;
  $('title').textContent = `s3tir viewer: ${info.run}`;
  document.querySelectorAll('.unit').forEach((e) => {
    e.textContent = info.unit;
  });
  const note = info.units_note;
  $('note').textContent = `${$('note').textContent} ${note[0].toUpperCase()}${note.slice(1)}.`;
  for (const p of info.palettes) $('palette').add(new Option(p.name, p.name));
  const wanted = params.get('palette') || info.default_palette;
  state.palette = info.palettes.find((p) => p.name === wanted) || info.palettes[0];
  $('palette').value = state.palette.name;
  $('shade').checked = params.get('shade') === '1';
  if (!info.meshes.length) {
    fail(`${info.run} has no mesh: run \`s3tir-train mesh RUN\` (or start the viewer again; it meshes a run without one)`);
    return;
  }
  for (const m of info.meshes) $('mesh').add(new Option(`${m.name} (${m.triangles} triangles)`, m.name));
  const first = info.meshes.find((m) => m.name === params.get('mesh')) || info.meshes[0];
  $('mesh').value = first.name;
  resize();
  await showMesh(first);

  $('mesh').addEventListener('change', () => {
    const m = info.meshes.find((x) => x.name === $('mesh').value);
    showMesh(m).catch((e) => fail(String(e.message || e)));
  });
  $('palette').addEventListener('change', () => {
    state.palette = info.palettes.find((p) => p.name === $('palette').value);
    recolour();
  });
  for (const id of ['lo', 'hi']) {
    $(id).addEventListener('change', () => {
      const lo = Number.parseFloat($('lo').value);
      const hi = Number.parseFloat($('hi').value);
      if (Number.isFinite(lo) && Number.isFinite(hi) && hi > lo) {
        state.lo = lo;
        state.hi = hi;
        recolour();
      }
    });
  }
  $('auto').addEventListener('click', () => {
    setRange(state.meshInfo.lo ?? 0, state.meshInfo.hi ?? 1);
    recolour();
  });
  $('shade').addEventListener('change', () => {
    state.mesh.material.dispose();
    state.mesh.material = material();
    render();
  });
  $('home').addEventListener('click', goHome);
  window.addEventListener('resize', resize);

  const pick = params.get('pick');
  const pickWorld = params.get('pickat');
  if (pick || pickWorld) {
    let [u, v] = (pick || '').split(',').map(Number);
    if (pickWorld) {
      // a click where the world point X, Y, Z appears on the canvas
      const ndc = new THREE.Vector3(...pickWorld.split(',').map(Number)).project(camera);
      [u, v] = [(ndc.x + 1) / 2, (1 - ndc.y) / 2];
    }
    const p = pickAt(u, v);
    showPick(p, true);
    recordPick(p);
  }
  render();
  document.body.dataset.ready = '1';
}

main().catch((e) => fail(String(e.message || e)));
