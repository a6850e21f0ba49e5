// The tandem viewer page: draws a session's sealed chunks as they arrive (one mesh per chunk,
// never one giant buffer) and its unsealed band in another colour, from the small state the
// server pushes over server-sent events (/events); chunks are immutable resources
// (/chunk/N.drc), so a reload or a late browser fetches what it lacks and catches up.
// window.tandemView exposes what is drawn, for the browser test.
// A mesh of millions of triangles stays workable: every geometry (a chunk, the band, a file)
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
const sealedMaterial = material(0xb8c4d6);
const bandMaterial = material(0xff8a3d);
// The band was taken before the chunks sealed since: where both cover the same place, the
// sealed surface wins the depth test.
bandMaterial.polygonOffset = true;
bandMaterial.polygonOffsetFactor = 2;
bandMaterial.polygonOffsetUnits = 2;
const sealedGroup = new THREE.Group();
scene.add(sealedGroup);
const bandGroup = new THREE.Group();
scene.add(bandGroup);
// The sealed part's box, grown as chunks arrive (not recomputed over every chunk).
const sealedBox = new THREE.Box3();

const draco = new DRACOLoader();
draco.setDecoderPath('/three/examples/jsm/libs/draco/');

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
  const box = sealedBox.clone();
  for (const m of bandGroup.children) box.union(m.geometry.boundingBox);
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
  for (const m of [sealedMaterial, bandMaterial]) {
    m.clippingPlanes = on ? [clipPlane] : [];
    m.needsUpdate = true;
  }
  requestRender(true);
}
$('clip').addEventListener('change', updateClip);
$('clip-at').addEventListener('input', updateClip);
$('reset').addEventListener('click', () => { userMoved = false; fit(); requestRender(true); });

// --- data ----------------------------------------------------------------------------------
const view = window.tandemView = {
  chunksDrawn: 0, sealedTriangles: 0, bandTriangles: 0, fileTriangles: 0, frames: 0,
  get trianglesDrawn() { return this.sealedTriangles + this.bandTriangles + this.fileTriangles; },
  state: null, finished: false, errors: [],
  // Whether everything added so far is on screen (no frame waiting to be drawn).
  get rendered() { return !frameQueued && dataTimer === null; },
  // World boxes of what is drawn ([min, max] corners), for tests and debugging.
  boxes() {
    const box = (o) => { const b = new THREE.Box3().expandByObject(o); return b.isEmpty() ? null : [b.min.toArray(), b.max.toArray()]; };
    return { sealed: box(sealedGroup), band: box(bandGroup) };
  },
  // The three.js meshes drawn and the largest one's triangles (every one is a buffer of its own).
  meshes() {
    const all = [...sealedGroup.children, ...bandGroup.children];
    return { count: all.length, maxTriangles: Math.max(0, ...all.map((m) => triangles(m.geometry))),
             pieceLimit: MAX_PIECE_TRIANGLES };
  },
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

function pieces(geometry) {
  const n = triangles(geometry);
  if (n <= MAX_PIECE_TRIANGLES) return [geometry];
  // Normals over the whole geometry first, so that the pieces' normals agree at their seams.
  if (!geometry.attributes.normal) geometry.computeVertexNormals();
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

// Adds `geometry` to `group` (as pieces); returns its triangles.
function addGeometry(geometry, group, mat) {
  let added = 0;
  for (const g of pieces(geometry)) {
    if (!g.attributes.normal) g.computeVertexNormals();
    g.computeBoundingBox();
    group.add(new THREE.Mesh(g, mat));
    if (group === sealedGroup) sealedBox.union(g.boundingBox);
    added += triangles(g);
  }
  requestRender();
  return added;
}

function clearBand() {
  for (const m of bandGroup.children) m.geometry.dispose();
  bandGroup.clear();
  view.bandTriangles = 0;
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
  for (const g of geometries) view.fileTriangles += addGeometry(g, sealedGroup, sealedMaterial);
}

function number(n) { return Number(n).toLocaleString('en-US'); }

function showPanel(s) {
  $('status').textContent = s.error ? 'failed' : s.finished ? 'finished' : s.session ? 'live' : 'waiting…';
  $('title').textContent = [s.description, s.session && `session ${s.session}`].filter(Boolean).join(' · ');
  $('slices-sent').textContent = number(s.slices_sent) + (s.nz > 0 ? ` / ${number(s.nz)}` : '');
  $('slices-meshed').textContent = number(s.slices_meshed);
  $('front').textContent = s.slices_meshed > 0 ? number(s.slices_meshed - 1) : '–';
  $('held').textContent = number(s.triangles_held);
  $('sealed').textContent = number(s.triangles_sealed);
  $('chunks').textContent = `${number(view.chunksDrawn)} / ${number(s.chunks)}`;
  $('drawn').textContent = number(view.trianglesDrawn);
  const fraction = s.finished ? 1 : s.nz > 0 ? s.slices_meshed / s.nz : 0;
  $('fill').style.width = `${Math.min(100, 100 * fraction)}%`;
  $('bar').hidden = s.nz <= 0 && !s.finished;
  if (s.error) {
    $('error').hidden = false;
    $('error').textContent = s.error;
  }
  if (s.metrics && $('metrics').hidden) {
    // The main figures first; the rest folded.
    const main = ['triangles_final', 'vertices_final', 'slices', 'error_threshold', 'error_max',
                  'peak_triangles', 'time_wall_s', 'bytes_sent', 'sealed_chunks'];
    const row = ([k, v]) => `<tr><th>${k}</th><td id="metric-${k}">${
      typeof v === 'number' && !Number.isInteger(v) ? v.toPrecision(5) : v}</td></tr>`;
    const scalars = Object.entries(s.metrics).filter(([, v]) => v !== null && typeof v !== 'object' && v !== '');
    const first = main.map((k) => scalars.find(([key]) => key === k)).filter(Boolean);
    const rest = scalars.filter(([k]) => !main.includes(k));
    $('metrics').innerHTML = '<tr><th colspan="2">final metrics</th></tr>' + first.map(row).join('') +
      `<tr><td colspan="2"><details><summary>all metrics</summary><table>${rest.map(row).join('')}</table></details></td></tr>`;
    $('metrics').hidden = false;
  }
}

// One state at a time, newest wins: a slow decode skips intermediate states, never chunks.
let latest = null, busy = false, loadedFiles = 0, bandVersion = 0;
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
        view.sealedTriangles += addGeometry(g, sealedGroup, sealedMaterial);
        view.chunksDrawn = i + 1;
        if (!userMoved) fit();
        showPanel(s);
      }
      while (loadedFiles < s.files.length) await loadFile(s.files[loadedFiles++]);
      const band = s.band;
      if (!band && bandGroup.children.length > 0) {
        clearBand();
      } else if (band && band.version !== bandVersion) {
        try {
          const g = await decodeDraco(await bytes(`/band/${band.version}.drc`));
          clearBand();
          view.bandTriangles = addGeometry(g, bandGroup,
                                           band.band_only ? bandMaterial : (s.finished ? sealedMaterial : bandMaterial));
          bandVersion = band.version;
        } catch (e) {
          // Superseded while it was fetched (HTTP 404): the next state names the new one.
        }
      }
      if (!userMoved) fit();
      if ($('clip').checked) updateClip();
      view.finished = s.finished;
      showPanel(s);
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
    apply();
  };
  events.onerror = () => {
    // The browser reconnects by itself; a finished session's viewer may simply be gone.
    $('status').textContent = view.finished ? 'finished (viewer closed)' : 'reconnecting…';
  };
}
connect();
