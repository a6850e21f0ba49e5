// The tandem viewer page: draws a session's surfaces as they grow, from the small state the
// server pushes over server-sent events (/events): every surface's sealed chunks as they
// arrive (one mesh per chunk, never one giant buffer) and its latest band (the part not
// sealed yet) or, unsealed, its latest whole partial mesh, in a shade of its own; then the
// final meshes. Chunks are immutable resources (/chunk/N.drc), so a reload or a late browser
// fetches what it lacks and catches up.
// Chunks carry their vertices' global ids (Draco generic attribute): normals are summed by
// id over every chunk of a surface, so a vertex on a chunk border has one normal in every
// chunk that holds it, and no seam shows (IdNormals below).
// window.tandemView exposes what is drawn, window.__tandemTest the geometry, for the tests.
// A mesh of millions of triangles stays workable: every geometry (a chunk, a band, a file)
// is drawn as pieces of at most MAX_PIECE_TRIANGLES, the view is redrawn only when something
// changed (never in a loop), and adding a chunk costs the same whatever came before it.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { DRACOLoader } from 'three/addons/loaders/DRACOLoader.js';
import { PLYLoader } from 'three/addons/loaders/PLYLoader.js';
import { OBJLoader } from 'three/addons/loaders/OBJLoader.js';
import { STLLoader } from 'three/addons/loaders/STLLoader.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';

const token = new URLSearchParams(location.search).get('token');
const withToken = (url) =>
  token ? `${url}${url.includes('?') ? '&' : '?'}token=${encodeURIComponent(token)}` : url;
const $ = (id) => document.getElementById(id);

// --- scene -------------------------------------------------------------------------------
const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio);
renderer.localClippingEnabled = true;
$('view').appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0x16181d);
const camera = new THREE.PerspectiveCamera(35, 1, 0.01, 1e7);
camera.up.set(0, 0, 1);  // slices stack along z: the scan grows upwards
scene.add(camera);
scene.add(new THREE.HemisphereLight(0xffffff, 0x303540, 1.4));
const keyLight = new THREE.DirectionalLight(0xffffff, 2.0);
keyLight.position.set(1, 2, 3);
camera.add(keyLight);
// Drawn on demand, at most once a frame: a user's move at once; new data no sooner than
// three frame times after the last frame (measured from one frame to the next animation
// frame), so that a software rasterizer that needs seconds for millions of triangles spends
// most of its time on the data, not on redrawing each chunk.
let frameQueued = false, dataTimer = null, lastFrameAt = -Infinity, frameCost = 16, probing = false;
function frame() {
  frameQueued = false;
  const t0 = performance.now();
  renderer.render(scene, camera);
  lastFrameAt = t0;
  view.frames++;
  if (!probing) {
    probing = true;
    requestAnimationFrame(() => { probing = false; frameCost = performance.now() - t0; });
  }
}
function requestRender(now = false) {
  if (frameQueued) return;
  const wait = now ? 0 : lastFrameAt + Math.max(100, 3 * frameCost) - performance.now();
  if (wait <= 0) {
    if (dataTimer !== null) { clearTimeout(dataTimer); dataTimer = null; }
    frameQueued = true;
    requestAnimationFrame(frame);
  } else if (dataTimer === null) {
    dataTimer = setTimeout(() => { dataTimer = null; requestRender(true); }, wait);
  }
}

const controls = new OrbitControls(camera, renderer.domElement);
let userMoved = false;  // until the user moves the view, it follows the growing mesh
controls.addEventListener('start', () => { userMoved = true; });
controls.addEventListener('change', () => requestRender(true));

const clipPlane = new THREE.Plane(new THREE.Vector3(0, 0, -1), 0);
const material = (color) => new THREE.MeshStandardMaterial({
  color, roughness: 0.55, metalness: 0.05, side: THREE.DoubleSide });

// --- normals by global id -----------------------------------------------------------------
// Area-weighted normal sums by global vertex id over every chunk of one surface, and where
// each id occurs (piece, vertex), so that a chunk that arrives later and shares border
// vertices with earlier ones updates their normals there too: once both chunks of a border
// are drawn, its vertices have the same normal in both, the one the welded mesh has.
class IdNormals {
  constructor() {
    this.sum = new Float32Array(0);   // 3 per id
    this.head = new Int32Array(0);    // id -> its latest occurrence (-1: none)
    this.stamp = new Int32Array(0);   // id -> the last chunk that touched it
    this.occPiece = new Int32Array(1024);
    this.occVertex = new Int32Array(1024);
    this.occNext = new Int32Array(1024);
    this.occCount = 0;
    this.pieces = [];  // [{normal, position}] attributes, by piece number
    this.serial = 0;
  }
  growIds(maxId) {
    if (maxId < this.head.length) return;
    let n = Math.max(1024, this.head.length);
    while (n <= maxId) n *= 2;
    const sum = new Float32Array(3 * n); sum.set(this.sum); this.sum = sum;
    const head = new Int32Array(n).fill(-1); head.set(this.head); this.head = head;
    const stamp = new Int32Array(n); stamp.set(this.stamp); this.stamp = stamp;
  }
  growOccurrences(extra) {
    if (this.occCount + extra <= this.occPiece.length) return;
    let n = this.occPiece.length;
    while (n < this.occCount + extra) n *= 2;
    for (const name of ['occPiece', 'occVertex', 'occNext']) {
      const a = new Int32Array(n); a.set(this[name]); this[name] = a;
    }
  }
  // `geometries`: the pieces of one chunk, each with its position and index and its ids in
  // userData.ids. Sets their normal attributes, and updates those of earlier chunks' vertices
  // they share. Returns false, changing nothing, when an id already seen names a vertex at
  // another place (chunks of other surfaces or runs in one folder): the caller then shades
  // the chunk by itself.
  add(geometries) {
    let maxId = -1, vertices = 0;
    for (const g of geometries) {
      for (const id of g.userData.ids) if (id > maxId) maxId = id;
      vertices += g.userData.ids.length;
    }
    this.growIds(maxId);
    const { sum, head } = this;
    for (const g of geometries) {
      const ids = g.userData.ids, p = g.attributes.position.array;
      for (let v = 0; v < ids.length; v++) {
        const o = head[ids[v]];
        if (o < 0) continue;
        const q = this.pieces[this.occPiece[o]].position.array, w = 3 * this.occVertex[o];
        if (q[w] !== p[3 * v] || q[w + 1] !== p[3 * v + 1] || q[w + 2] !== p[3 * v + 2]) return false;
      }
    }
    for (const g of geometries) {
      const ids = g.userData.ids, p = g.attributes.position.array, index = g.index.array;
      for (let t = 0; t < index.length; t += 3) {
        const a = 3 * index[t], b = 3 * index[t + 1], c = 3 * index[t + 2];
        const ux = p[b] - p[a], uy = p[b + 1] - p[a + 1], uz = p[b + 2] - p[a + 2];
        const vx = p[c] - p[a], vy = p[c + 1] - p[a + 1], vz = p[c + 2] - p[a + 2];
        const nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
        for (let k = 0; k < 3; k++) {
          const s = 3 * ids[index[t + k]];
          sum[s] += nx; sum[s + 1] += ny; sum[s + 2] += nz;
        }
      }
    }
    const serial = ++this.serial, touched = new Set();
    this.growOccurrences(vertices);
    for (const g of geometries) {
      const ids = g.userData.ids;
      const normal = new THREE.BufferAttribute(new Float32Array(3 * ids.length), 3);
      g.setAttribute('normal', normal);
      const piece = this.pieces.length;
      this.pieces.push({ normal, position: g.attributes.position });
      for (let v = 0; v < ids.length; v++) {
        const id = ids[v];
        if (this.stamp[id] !== serial) {  // earlier occurrences: their normal changed too
          this.stamp[id] = serial;
          for (let o = head[id]; o >= 0; o = this.occNext[o]) {
            const earlier = this.pieces[this.occPiece[o]];
            this.normalInto(id, earlier.normal.array, this.occVertex[o]);
            touched.add(earlier.normal);
          }
        }
        const o = this.occCount++;
        this.occPiece[o] = piece;
        this.occVertex[o] = v;
        this.occNext[o] = head[id];
        head[id] = o;
        this.normalInto(id, normal.array, v);
      }
    }
    for (const n of touched) n.needsUpdate = true;
    return true;
  }
  normalInto(id, out, v) {
    const s = this.sum, x = s[3 * id], y = s[3 * id + 1], z = s[3 * id + 2];
    const length = Math.hypot(x, y, z) || 1;
    out[3 * v] = x / length; out[3 * v + 1] = y / length; out[3 * v + 2] = z / length;
  }
}

// Each surface (--iso A,B,...) in colours of its own: a muted one for what is settled (sealed
// chunks, the final mesh) and a vivid one for what still changes (the band, a preview).
const PALETTE = [
  ['#b8c4d6', '#ff8a3d'], ['#8fd1a8', '#e03fd0'], ['#e0b0c8', '#2fb7ff'], ['#d8cf8a', '#7a5cff'],
  ['#9fd7dd', '#ff3d5a'], ['#c9b3e6', '#7ed321'], ['#e3b892', '#00c2a8'], ['#aab4a0', '#ffd000'],
];

// What one surface draws: its chunks and files (sealed), its band or preview, the normals
// of its chunks by global id.
class Surface {
  constructor(index) {
    this.index = index;
    [this.sealedColor, this.bandColor] = PALETTE[index % PALETTE.length];
    this.sealedMaterial = material(this.sealedColor);
    this.bandMaterial = material(this.bandColor);
    // The band was taken before the chunks sealed since: where both cover the same place,
    // the sealed surface wins the depth test.
    this.bandMaterial.polygonOffset = true;
    this.bandMaterial.polygonOffsetFactor = 2;
    this.bandMaterial.polygonOffsetUnits = 2;
    this.sealedGroup = new THREE.Group();
    this.bandGroup = new THREE.Group();
    this.root = new THREE.Group();
    this.root.add(this.sealedGroup, this.bandGroup);
    scene.add(this.root);
    this.sealedBox = new THREE.Box3();  // grown as chunks arrive, never recomputed
    this.normals = new IdNormals();
    this.bandVersion = 0;
    this.bandOnly = true;
    this.sealedTriangles = 0;
    this.bandTriangles = 0;
    this.chunks = 0;
  }
  materials() { return [this.sealedMaterial, this.bandMaterial]; }
  // A colour of its own (a label session's label: its table's colour or a hue of its own),
  // for what is settled and what still changes alike.
  setColor(color) {
    if (this.customColor === color) return;
    this.customColor = color;
    this.sealedColor = this.bandColor = color;
    for (const m of this.materials()) m.color.set(color);
    requestRender();
  }
}
const surfaces = [];
function surface(i) {
  while (surfaces.length <= i) surfaces.push(new Surface(surfaces.length));
  return surfaces[i];
}
surface(0);

const draco = new DRACOLoader();
draco.setDecoderPath('/three/examples/jsm/libs/draco/');
// Sealed chunks name their vertices in a generic attribute (global ids); other meshes have
// none and decode as before.
draco.defaultAttributeIDs.id = 'GENERIC';
draco.defaultAttributeTypes.id = 'Uint32Array';

function resize() {
  const w = $('view').clientWidth, h = $('view').clientHeight;
  renderer.setSize(w, h);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
  requestRender(true);
}
window.addEventListener('resize', resize);
resize();

function bounds() {
  const box = new THREE.Box3();
  for (const s of surfaces) {
    if (!s.root.visible) continue;
    box.union(s.sealedBox);
    for (const m of s.bandGroup.children) box.union(m.geometry.boundingBox);
  }
  return box;
}

function fit() {
  const box = bounds();
  if (box.isEmpty()) return;
  const center = box.getCenter(new THREE.Vector3());
  const radius = Math.max(box.getSize(new THREE.Vector3()).length() / 2, 1e-6);
  const distance = radius / Math.sin(THREE.MathUtils.degToRad(camera.fov / 2)) * 1.05;
  const direction = new THREE.Vector3(1.0, -1.6, 0.8).normalize();
  camera.position.copy(center).addScaledVector(direction, distance);
  camera.near = distance / 100;
  camera.far = distance * 100;
  camera.updateProjectionMatrix();
  controls.target.copy(center);
  controls.update();
  requestRender();
}

function updateClip() {
  const on = $('clip').checked;
  const box = bounds();
  if (!box.isEmpty()) {
    const t = Number($('clip-at').value) / 1000;
    clipPlane.constant = box.min.z + t * (box.max.z - box.min.z);
  }
  for (const s of surfaces) {
    for (const m of s.materials()) {
      m.clippingPlanes = on ? [clipPlane] : [];
      m.needsUpdate = true;
    }
  }
  requestRender(true);
}
$('clip').addEventListener('change', updateClip);
$('clip-at').addEventListener('input', updateClip);
$('reset').addEventListener('click', () => { userMoved = false; fit(); requestRender(true); });

// --- data ----------------------------------------------------------------------------------
const view = window.tandemView = {
  chunksDrawn: 0, fileTriangles: 0, frames: 0,
  get sealedTriangles() { return surfaces.reduce((n, s) => n + s.sealedTriangles, 0); },
  get bandTriangles() { return surfaces.reduce((n, s) => n + s.bandTriangles, 0); },
  get trianglesDrawn() { return this.sealedTriangles + this.bandTriangles + this.fileTriangles; },
  state: null, finished: false, errors: [],
  // Whether everything added so far is on screen (no frame waiting to be drawn).
  get rendered() { return !frameQueued && dataTimer === null; },
  // World boxes of what is drawn ([min, max] corners), for tests and debugging.
  boxes() {
    const box = (objects) => {
      const b = new THREE.Box3();
      for (const o of objects) b.expandByObject(o);
      return b.isEmpty() ? null : [b.min.toArray(), b.max.toArray()];
    };
    return { sealed: box(surfaces.map((s) => s.sealedGroup)), band: box(surfaces.map((s) => s.bandGroup)) };
  },
  // The three.js meshes drawn and the largest one's triangles (every one is a buffer of its own).
  meshes() {
    const all = surfaces.flatMap((s) => [...s.sealedGroup.children, ...s.bandGroup.children]);
    return { count: all.length, maxTriangles: Math.max(0, ...all.map((m) => triangles(m.geometry))),
             pieceLimit: MAX_PIECE_TRIANGLES };
  },
  // Each surface: its label, colours, and what it draws.
  surfaces() {
    return surfaces.map((s) => ({ label: label(s.index), sealedColor: s.sealedColor, bandColor: s.bandColor,
                                  chunks: s.chunks, sealedTriangles: s.sealedTriangles,
                                  bandTriangles: s.bandTriangles, visible: s.root.visible }));
  },
  // The progress bar as shown: {value, max, phase, text}.
  progress() {
    const bar = $('bar');
    return { value: Number(bar.getAttribute('aria-valuenow')), max: Number(bar.getAttribute('aria-valuemax')),
             phase: $('status').textContent, text: $('finishing').textContent };
  },
};
// For the browser tests: every mesh with what it shows (kind: chunk, band or file), and the
// statuses the page went through.
window.__tandemTest = {
  meshes() {
    return surfaces.flatMap((s) => [...s.sealedGroup.children, ...s.bandGroup.children].map((m) => ({
      surface: s.index, kind: m.userData.kind, chunk: m.userData.chunk, geometry: m.geometry,
      ids: m.geometry.userData.ids || null })));
  },
  statuses: [],
};

async function bytes(url) {
  const response = await fetch(withToken(url));
  if (!response.ok) throw new Error(`${url}: HTTP ${response.status}`);
  return response.arrayBuffer();
}
const decodeDraco = (buffer) => new Promise((resolve, reject) => draco.parse(buffer, resolve, reject));
const triangles = (g) => (g.index ? g.index.count : g.attributes.position.count) / 3;

// Largest piece drawn as one mesh: a chunk, band or file with more triangles is cut into
// runs of consecutive triangles (meshers and files list them roughly in space order), each
// with only the vertices it uses, so no buffer grows with the whole mesh and the pieces
// out of view are culled.
const MAX_PIECE_TRIANGLES = 65536;

function attributeOf(a) {
  return a.isInterleavedBufferAttribute ? a.clone() : a;  // clone() de-interleaves
}

// `normals`: compute them over the whole geometry before it is cut, so that the pieces'
// normals agree at their seams (chunks get theirs by id instead).
function pieces(geometry, normals) {
  const n = triangles(geometry);
  if (n <= MAX_PIECE_TRIANGLES) return [geometry];
  if (normals && !geometry.attributes.normal) geometry.computeVertexNormals();
  const names = Object.keys(geometry.attributes);
  const attributes = names.map((name) => attributeOf(geometry.attributes[name]));
  const out = [];
  if (!geometry.index) {  // triangle soup (STL): consecutive runs of vertices
    for (let t = 0; t < n; t += MAX_PIECE_TRIANGLES) {
      const end = Math.min(n, t + MAX_PIECE_TRIANGLES);
      const piece = new THREE.BufferGeometry();
      names.forEach((name, k) => {
        const a = attributes[k];
        piece.setAttribute(name, new THREE.BufferAttribute(
          a.array.slice(3 * t * a.itemSize, 3 * end * a.itemSize), a.itemSize, a.normalized));
      });
      out.push(piece);
    }
    return out;
  }
  const index = geometry.index.array;
  const vertices = geometry.attributes.position.count;
  const local = new Int32Array(vertices);        // a vertex's index in the current piece
  const owner = new Int32Array(vertices).fill(-1); // the piece that gave it that index
  const used = new Int32Array(3 * MAX_PIECE_TRIANGLES);
  for (let t = 0, p = 0; t < n; t += MAX_PIECE_TRIANGLES, p++) {
    const first = 3 * t, last = 3 * Math.min(n, t + MAX_PIECE_TRIANGLES);
    let count = 0;
    const pieceIndex = new Uint32Array(last - first);
    for (let k = first; k < last; k++) {
      const v = index[k];
      if (owner[v] !== p) { owner[v] = p; local[v] = count; used[count++] = v; }
      pieceIndex[k - first] = local[v];
    }
    const piece = new THREE.BufferGeometry();
    piece.setIndex(new THREE.BufferAttribute(count <= 65536 ? Uint16Array.from(pieceIndex) : pieceIndex, 1));
    names.forEach((name, k) => {
      const a = attributes[k], size = a.itemSize, from = a.array;
      const to = new from.constructor(count * size);
      for (let i = 0; i < count; i++) {
        const src = used[i] * size, dst = i * size;
        for (let c = 0; c < size; c++) to[dst + c] = from[src + c];
      }
      piece.setAttribute(name, new THREE.BufferAttribute(to, size, a.normalized));
    });
    out.push(piece);
  }
  geometry.dispose();
  return out;
}

// Adds `geometry` to `group` (as pieces) with `mat`; returns its triangles. A sealed chunk
// (userData.chunk set) is shaded by global id across chunks, everything else by itself.
function addGeometry(geometry, s, group, mat, userData) {
  const chunk = userData.kind === 'chunk' && geometry.attributes.id && geometry.index;
  const parts = pieces(geometry, !chunk);
  if (chunk) {
    for (const g of parts) {  // the ids are the page's, not the GPU's
      g.userData.ids = g.attributes.id.array;
      g.deleteAttribute('id');
    }
    if (!s.normals.add(parts)) for (const g of parts) g.computeVertexNormals();
  }
  let added = 0;
  for (const g of parts) {
    if (!g.attributes.normal) g.computeVertexNormals();
    g.computeBoundingBox();
    const mesh = new THREE.Mesh(g, mat);
    mesh.userData = { ...userData };
    group.add(mesh);
    if (group === s.sealedGroup) s.sealedBox.union(g.boundingBox);
    added += triangles(g);
  }
  requestRender();
  return added;
}

function clearBand(s) {
  for (const m of s.bandGroup.children) m.geometry.dispose();
  s.bandGroup.clear();
  s.bandTriangles = 0;
  requestRender();
}

async function loadFile(file) {
  const url = `/file/${encodeURIComponent(file.name)}`;
  const data = await bytes(url);
  let geometries = [];
  if (file.format === 'drc') geometries = [await decodeDraco(data)];
  else if (file.format === 'ply') geometries = [new PLYLoader().parse(data)];
  else if (file.format === 'stl') geometries = [new STLLoader().parse(data)];
  else if (file.format === 'obj') {
    new OBJLoader().parse(new TextDecoder().decode(data)).traverse((o) => { if (o.isMesh) geometries.push(o.geometry); });
  } else if (file.format === 'glb') {
    const gltf = await new Promise((resolve, reject) => {
      const loader = new GLTFLoader();
      loader.setDRACOLoader(draco);
      loader.parse(data, '', resolve, reject);
    });
    gltf.scene.updateMatrixWorld(true);
    gltf.scene.traverse((o) => { if (o.isMesh) geometries.push(o.geometry.clone().applyMatrix4(o.matrixWorld)); });
  }
  const s = surface(0);
  for (const g of geometries) {
    if (g.attributes.id) g.deleteAttribute('id');
    view.fileTriangles += addGeometry(g, s, s.sealedGroup, s.sealedMaterial, { kind: 'file' });
  }
}

// --- the panel -------------------------------------------------------------------------------
function number(n) { return Number(n).toLocaleString('en-US'); }
function label(i) {
  const known = view.state && view.state.surfaces && view.state.surfaces[i];
  return known ? known.label : surfaces.length > 1 ? `surface ${i}` : 'surface';
}
function seconds(s) { return s < 10 ? `${s.toFixed(1)} s` : s < 120 ? `${Math.round(s)} s` : `${Math.round(s / 60)} min`; }
function escapeHtml(text) {
  return String(text).replace(/[&<>"']/g, (c) => `&#${c.charCodeAt(0)};`);
}

// The legend: one row per surface, its two colours and a box that shows or hides it.
let legendKey = '';
function showLegend(s) {
  const sealed = s.chunks > 0 || (s.bands || []).some((b) => b && b.band_only);
  const key = JSON.stringify([surfaces.length, surfaces.map((x) => [label(x.index), x.sealedColor]), sealed, !!s.finished]);
  if (key === legendKey) return;
  legendKey = key;
  const [settled, changing] = sealed ? ['sealed', 'not sealed yet'] : ['final', 'preview'];
  $('legend').innerHTML = surfaces.map((x) => `<label class="surface" data-surface="${x.index}">` +
    `<input type="checkbox" ${x.root.visible ? 'checked' : ''}> ` +
    `<span class="swatch" style="background:${x.sealedColor}" title="${settled}"></span>` +
    `<span class="swatch" style="background:${x.bandColor}" title="${changing}"></span> ` +
    `${escapeHtml(label(x.index))}</label>`).join('') +
    `<div class="note">first colour: ${settled}; second: ${changing}</div>`;
  for (const box of $('legend').querySelectorAll('label.surface')) {
    box.querySelector('input').addEventListener('change', (e) => {
      surfaces[Number(box.dataset.surface)].root.visible = e.target.checked;
      requestRender(true);
    });
  }
}

// The slices meshed against the depth (or, following a scan of unknown depth, the slices on
// disk so far); after the last slice, the finishing state until the end.
let stateAt = 0;  // performance.now() when the state shown arrived
function phase(s) {
  if (s.error) return 'failed';
  if (s.finished) return 'finished';
  if (s.finishing) return 'finishing';
  return s.session || s.slices_meshed > 0 ? 'live' : 'waiting…';
}
function showProgress(s) {
  const status = phase(s);
  $('status').textContent = status;
  const statuses = window.__tandemTest.statuses;
  if (statuses[statuses.length - 1] !== status) statuses.push(status);
  const depth = s.nz > 0 ? s.nz : s.slices_on_disk > 0 ? s.slices_on_disk : 0;
  $('slices-meshed').textContent = number(s.slices_meshed) +
    (s.nz > 0 ? ` / ${number(s.nz)}` : s.slices_on_disk >= 0 ? ` / ${number(s.slices_on_disk)} on disk` : '');
  const value = s.finished && !s.error ? depth || 1 : Math.min(s.slices_meshed, depth);
  const bar = $('bar');
  bar.setAttribute('aria-valuenow', String(value));
  bar.setAttribute('aria-valuemax', String(depth || (s.finished ? 1 : 0)));
  bar.classList.toggle('finishing', status === 'finishing');
  bar.hidden = depth <= 0 && !s.finished;
  $('fill').style.width = `${depth > 0 || s.finished ? Math.min(100, 100 * value / (depth || 1)) : 0}%`;
  const f = s.finishing;
  let text = '';
  if (f && status === 'finishing') {
    const elapsed = f.elapsed_s + (performance.now() - stateAt) / 1000;
    const left = f.estimate_s - elapsed;
    text = `every slice is in: simplifying and encoding ${number(f.triangles)} triangles, ` +
      (left > 0 ? `about ${seconds(left)} left` : `${seconds(elapsed)} so far (longer than the estimate of ${seconds(f.estimate_s)})`);
  } else if (f && s.finished) {
    text = `finished ${seconds(f.elapsed_s)} after the last slice`;
  } else if (status === 'live' && s.nz <= 0 && s.slices_on_disk >= 0 && s.slices_meshed >= s.slices_on_disk) {
    text = 'waiting for the next slice';
  }
  $('finishing').textContent = text;
  $('finishing').hidden = text === '';
}
setInterval(() => { if (view.state && phase(view.state) === 'finishing') showProgress(view.state); }, 1000);

function showPanel(s) {
  showProgress(s);
  $('title').textContent = [s.description, s.session && `session ${s.session}`].filter(Boolean).join(' · ');
  $('slices-sent').textContent = number(s.slices_sent) + (s.nz > 0 ? ` / ${number(s.nz)}` : '');
  $('front').textContent = s.slices_meshed > 0 ? number(s.slices_meshed - 1) : '–';
  $('held').textContent = number(s.triangles_held);
  $('sealed').textContent = number(s.triangles_sealed);
  $('chunks').textContent = `${number(view.chunksDrawn)} / ${number(s.chunks)}`;
  $('drawn').textContent = number(view.trianglesDrawn);
  showLegend(s);
  if (s.error) {
    $('error').hidden = false;
    $('error').textContent = s.error;
  }
  if (s.metrics && $('metrics').hidden) showMetrics(s.metrics);
}

// The final metrics: the main figures of each surface (rows of their own, under its label),
// the rest folded. Surface 0's cells have the ids metric-NAME, surface i's metric-NAME-i.
function showMetrics(metrics) {
  const all = Array.isArray(metrics) ? metrics : [metrics];
  const main = ['triangles_final', 'vertices_final', 'slices', 'error_threshold', 'error_max',
                'peak_triangles', 'time_wall_s', 'bytes_sent', 'sealed_chunks',
                // a label session's labels, one object each
                'label', 'name', 'triangles', 'vertices', 'area', 'volume', 'euler', 'components',
                'closed'];
  let html = '<tr><th colspan="2">final metrics</th></tr>';
  all.forEach((m, i) => {
    if (!m || typeof m !== 'object') return;
    const id = (k) => (i === 0 ? `metric-${k}` : `metric-${k}-${i}`);
    const row = ([k, v]) => `<tr><th>${escapeHtml(k)}</th><td id="${id(k)}" data-surface="${i}" data-metric="${escapeHtml(k)}">${
      typeof v === 'number' && !Number.isInteger(v) ? v.toPrecision(5) : escapeHtml(v)}</td></tr>`;
    const scalars = Object.entries(m).filter(([, v]) => v !== null && typeof v !== 'object' && v !== '');
    const first = main.map((k) => scalars.find(([key]) => key === k)).filter(Boolean);
    const rest = scalars.filter(([k]) => !main.includes(k));
    if (all.length > 1) {
      const s = surface(i);
      html += `<tr class="surface-head"><th colspan="2"><span class="swatch" style="background:${s.sealedColor}"></span> ${escapeHtml(label(i))}</th></tr>`;
    }
    html += first.map(row).join('') +
      `<tr><td colspan="2"><details><summary>all metrics</summary><table>${rest.map(row).join('')}</table></details></td></tr>`;
  });
  $('metrics').innerHTML = html;
  $('metrics').hidden = false;
}

// One state at a time, newest wins: a slow decode skips intermediate states, never chunks.
let latest = null, latestAt = 0, busy = false, loadedFiles = 0;
const PREFETCH = 4;
const pending = new Map();  // chunk index -> its decoded geometry, on the way
async function apply() {
  if (busy) return;
  busy = true;
  try {
    while (latest) {
      const s = latest;
      latest = null;
      view.state = s;
      stateAt = latestAt;
      for (let i = 0; i < Math.max(s.surfaces.length, s.bands.length); i++) {
        const known = s.surfaces[i];
        if (known && known.color) surface(i).setColor(known.color);
        else surface(i);
      }
      showPanel(s);
      while (view.chunksDrawn < s.chunks) {
        // A few chunks fetched and decoded at once (the decoder has several workers), drawn
        // in order.
        for (let j = view.chunksDrawn; j < Math.min(s.chunks, view.chunksDrawn + PREFETCH); j++) {
          if (!pending.has(j)) {
            const p = bytes(`/chunk/${j}.drc`).then(decodeDraco);
            p.catch(() => {});  // reported when awaited below
            pending.set(j, p);
          }
        }
        const i = view.chunksDrawn;
        const g = await pending.get(i);
        pending.delete(i);
        const owner = surface(s.chunk_surfaces[i] || 0);
        owner.sealedTriangles += addGeometry(g, owner, owner.sealedGroup, owner.sealedMaterial,
                                             { kind: 'chunk', chunk: i });
        owner.chunks++;
        view.chunksDrawn = i + 1;
        if (!userMoved) fit();
        showPanel(s);
      }
      while (loadedFiles < s.files.length) await loadFile(s.files[loadedFiles++]);
      for (let i = 0; i < s.bands.length; i++) {
        const band = s.bands[i], owner = surface(i);
        if (!band) {
          if (owner.bandGroup.children.length > 0) clearBand(owner);
          continue;
        }
        if (band.version !== owner.bandVersion) {
          try {
            const g = await decodeDraco(await bytes(`/band/${band.version}.drc`));
            clearBand(owner);
            owner.bandTriangles = addGeometry(g, owner, owner.bandGroup, owner.bandMaterial, { kind: 'band' });
            owner.bandVersion = band.version;
          } catch (e) {
            // Superseded while it was fetched (HTTP 404): the next state names the new one.
          }
        }
        // An unsealed surface's last mesh is its final one once the session is finished.
        const settled = s.finished && !s.error && !band.band_only;
        for (const m of owner.bandGroup.children) m.material = settled ? owner.sealedMaterial : owner.bandMaterial;
      }
      if (!userMoved) fit();
      if ($('clip').checked) updateClip();
      view.finished = s.finished;
      showPanel(s);
      requestRender();
    }
  } catch (e) {
    view.errors.push(String(e));
    $('error').hidden = false;
    $('error').textContent = String(e);
  } finally {
    busy = false;
  }
  if (latest) apply();
}

function connect() {
  const events = new EventSource(withToken('/events'));
  events.onmessage = (e) => {
    latest = JSON.parse(e.data);
    latestAt = performance.now();
    apply();
  };
  events.onerror = () => {
    // The browser reconnects by itself; a finished session's viewer may simply be gone.
    $('status').textContent = view.finished ? 'finished (viewer closed)' : 'reconnecting…';
  };
}
connect();
