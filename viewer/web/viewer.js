// The tandem viewer page: draws a session's sealed chunks as they arrive (one mesh per chunk,
// never one giant buffer) and its unsealed band in another colour, from the small state the
// server pushes over server-sent events (/events); chunks are immutable resources
// (/chunk/N.drc), so a reload or a late browser fetches what it lacks and catches up.
// window.tandemView exposes what is drawn, for the browser test.
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
const controls = new OrbitControls(camera, renderer.domElement);
let userMoved = false;  // until the user moves the view, it follows the growing mesh
controls.addEventListener('start', () => { userMoved = true; });

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
let bandMesh = null;

const draco = new DRACOLoader();
draco.setDecoderPath('/three/examples/jsm/libs/draco/');

function resize() {
  const w = $('view').clientWidth, h = $('view').clientHeight;
  renderer.setSize(w, h);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
}
window.addEventListener('resize', resize);
resize();

function bounds() {
  const box = new THREE.Box3();
  box.expandByObject(sealedGroup);
  if (bandMesh) box.expandByObject(bandMesh);
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
}
$('clip').addEventListener('change', updateClip);
$('clip-at').addEventListener('input', updateClip);
$('reset').addEventListener('click', () => { userMoved = false; fit(); });

function render() {
  requestAnimationFrame(render);
  controls.update();
  renderer.render(scene, camera);
}
render();

// --- data ----------------------------------------------------------------------------------
const view = window.tandemView = {
  chunksDrawn: 0, sealedTriangles: 0, bandTriangles: 0, fileTriangles: 0,
  get trianglesDrawn() { return this.sealedTriangles + this.bandTriangles + this.fileTriangles; },
  state: null, finished: false, errors: [],
  // World boxes of what is drawn ([min, max] corners), for tests and debugging.
  boxes() {
    const box = (o) => { const b = new THREE.Box3().expandByObject(o); return b.isEmpty() ? null : [b.min.toArray(), b.max.toArray()]; };
    return { sealed: box(sealedGroup), band: bandMesh ? box(bandMesh) : null };
  },
};

async function bytes(url) {
  const response = await fetch(withToken(url));
  if (!response.ok) throw new Error(`${url}: HTTP ${response.status}`);
  return response.arrayBuffer();
}
const decodeDraco = (buffer) => new Promise((resolve, reject) => draco.parse(buffer, resolve, reject));
const triangles = (g) => (g.index ? g.index.count : g.attributes.position.count) / 3;

function meshOf(geometry, mat) {
  if (!geometry.attributes.normal) geometry.computeVertexNormals();
  geometry.computeBoundingBox();
  return new THREE.Mesh(geometry, mat);
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
  for (const g of geometries) {
    sealedGroup.add(meshOf(g, sealedMaterial));
    view.fileTriangles += triangles(g);
  }
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
        const i = view.chunksDrawn;
        const g = await decodeDraco(await bytes(`/chunk/${i}.drc`));
        sealedGroup.add(meshOf(g, sealedMaterial));
        view.sealedTriangles += triangles(g);
        view.chunksDrawn = i + 1;
        if (!userMoved) fit();
        showPanel(s);
      }
      while (loadedFiles < s.files.length) await loadFile(s.files[loadedFiles++]);
      const band = s.band;
      if (!band && bandMesh) {
        scene.remove(bandMesh);
        bandMesh.geometry.dispose();
        bandMesh = null;
        view.bandTriangles = 0;
      } else if (band && band.version !== bandVersion) {
        try {
          const g = await decodeDraco(await bytes(`/band/${band.version}.drc`));
          if (bandMesh) { scene.remove(bandMesh); bandMesh.geometry.dispose(); }
          bandMesh = meshOf(g, band.band_only ? bandMaterial : (s.finished ? sealedMaterial : bandMaterial));
          scene.add(bandMesh);
          view.bandTriangles = triangles(g);
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
