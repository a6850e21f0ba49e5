// The viewer on a mesh of over a million triangles (issue 20: "keeps working on a mesh of
// millions of triangles, many chunks, never one giant buffer"), in headless Debian Chromium:
// `tandem view` of a folder of sealed chunks and of the same surface as one .ply, each must
// draw every triangle within a bounded time, as three.js meshes of at most
// MAX_MESH_TRIANGLES each, with no WebGL buffer over MAX_BUFFER_BYTES (counted by wrapping
// WebGL's bufferData, not by the page's own report), then draw nothing more while nothing
// changes, without a page error, and show the mesh in a screenshot. The input is made here: a dense gyroid (period 10 voxels) at full
// resolution, 128 x 128 x 80 voxels -> about 1.19 M triangles.
//   node tests/viewer/viewer_big_test.mjs BUILD_DIR
// Exit 0: passed; 1: failed; 77: skipped (no Chromium or node_modules, outside CI).
import { spawnSync } from 'node:child_process';
import fs from 'node:fs';
import path from 'node:path';
import { harness } from './browser_harness.mjs';

const { work, bin, check, start, sleep, waitFor, urlIn, startServer, launch, canvasShot, coverage, run } =
  harness(process.argv[2]);

const MAX_MESH_TRIANGLES = 65536;  // the page's pieces
const MAX_BUFFER_BYTES = 4 << 20;  // one piece's index is 0.75 MiB at most; the whole mesh's 14 MiB
// Per view, from the page's load to the last triangle drawn: 5-12 s measured on the 2 shared
// cores (SwiftShader, at a load of 5-10); a page that redraws in a loop or uploads one giant
// buffer takes longer, but the bound is for a page that stalls.
const VIEW_SECONDS = 120;

// sin x cos y + sin y cos z + sin z cos x, float32, x fastest, with its JSON sidecar.
function denseGyroid(file, [nx, ny, nz], period) {
  const w = (2 * Math.PI) / period;
  const table = (n, f) => Float32Array.from({ length: n }, (_, i) => f(w * i));
  const [sx, sy, sz] = [nx, ny, nz].map((n) => table(n, Math.sin));
  const [cx, cy, cz] = [nx, ny, nz].map((n) => table(n, Math.cos));
  const data = new Float32Array(nx * ny * nz);
  let o = 0;
  for (let k = 0; k < nz; k++) {
    for (let j = 0; j < ny; j++) {
      for (let i = 0; i < nx; i++) data[o++] = sx[i] * cy[j] + sy[j] * cz[k] + sz[k] * cx[i];
    }
  }
  const raw = file.replace(/\.json$/, '.raw');
  fs.writeFileSync(raw, Buffer.from(data.buffer));
  fs.writeFileSync(file, JSON.stringify({ dims: [nx, ny, nz], dtype: 'float32', raw_file: path.basename(raw) }));
}

// In the page before its scripts: the buffers handed to WebGL (how many, the largest) and
// the draw calls.
function countGl() {
  const seen = (window.__gl = { count: 0, maxBytes: 0, draws: 0 });
  for (const C of [WebGLRenderingContext, WebGL2RenderingContext]) {
    for (const name of ['drawElements', 'drawArrays']) {
      const draw = C.prototype[name];
      C.prototype[name] = function (...args) {
        seen.draws++;
        return draw.apply(this, args);
      };
    }
    const bufferData = C.prototype.bufferData;
    C.prototype.bufferData = function (target, data, ...rest) {
      const bytes = typeof data === 'number' ? data : data ? data.byteLength : 0;
      seen.count++;
      seen.maxBytes = Math.max(seen.maxBytes, bytes);
      return bufferData.call(this, target, data, ...rest);
    };
  }
}

const metricsOf = (file) => JSON.parse(fs.readFileSync(file, 'utf8'));

await run(async () => {
  const volume = path.join(work, 'dense.json');
  denseGyroid(volume, [128, 128, 80], 10);
  const ply = path.join(work, 'dense.ply');
  const made = spawnSync(bin('tandem'), ['extract', '--input', volume, '--iso', '0', '--no-simplify',
                                         '--out', ply, '--metrics', `${ply}.json`, '--quiet']);
  if (made.status !== 0) throw new Error(`tandem extract: ${made.stderr}`);
  const plyTriangles = metricsOf(`${ply}.json`).triangles_final;

  const address = await startServer();
  const chunks = path.join(work, 'chunks');
  const stream = start('tandem-client', ['stream', '--server', address, '--input', volume, '--iso', '0',
                                         '--no-simplify', '--seal', '--chunks', chunks,
                                         '--out', path.join(work, 'dense.drc'), '--metrics', path.join(work, 'stream.json')]);
  await stream.exited;
  if (stream.code !== 0) throw new Error(`tandem-client stream: ${stream.err}`);
  const streamTriangles = metricsOf(path.join(work, 'stream.json')).triangles_final;
  check(plyTriangles >= 1e6 && streamTriangles === plyTriangles, 'the input has over a million triangles',
        `${plyTriangles} in the .ply, ${streamTriangles} in ${fs.readdirSync(chunks).length} chunks`);

  const browser = await launch();
  async function viewAll(target, expected, what, shot) {
    // Bounds that only end a stuck run: the test kills the viewer when it is done.
    const viewer = start('tandem', ['view', target, '--view', '127.0.0.1:0', '--linger', '900']);
    const url = await waitFor(`tandem view ${what}`, () => urlIn(viewer), 240);
    const page = await browser.newPage({ viewport: { width: 960, height: 640 } });
    await page.addInitScript(countGl);
    const pageErrors = [];
    page.on('pageerror', (e) => pageErrors.push(e.message));
    page.on('crash', () => pageErrors.push('the page crashed'));
    const t0 = Date.now();
    await page.goto(url);
    const state = () => page.evaluate(() => {
      const v = window.tandemView;
      return v && { drawn: v.trianglesDrawn, finished: v.finished, chunks: v.chunksDrawn,
                    stateChunks: v.state ? v.state.chunks : -1, errors: v.errors,
                    rendered: v.rendered !== false };
    });
    let last = null;
    const done = await waitFor(`${what}: every triangle drawn`, async () => {
      last = await state();
      return last && last.finished && last.chunks === last.stateChunks && last.drawn === expected &&
             last.rendered ? last : null;
    }, VIEW_SECONDS).catch(() => null);
    const seconds = (Date.now() - t0) / 1000;
    check(done !== null, `tandem view ${what} draws all ${expected} triangles within ${VIEW_SECONDS} s`,
          done ? `${seconds.toFixed(1)} s` : `after ${seconds.toFixed(1)} s: ${JSON.stringify(last)}`);
    const meshes = await page.evaluate(() => (window.tandemView.meshes ? window.tandemView.meshes() : null));
    check(meshes !== null && meshes.maxTriangles <= MAX_MESH_TRIANGLES &&
          meshes.count >= Math.ceil(expected / MAX_MESH_TRIANGLES),
          `${what}: many meshes of at most ${MAX_MESH_TRIANGLES} triangles`, JSON.stringify(meshes));
    const buffers = await page.evaluate(() => window.__gl);
    check(buffers.maxBytes <= MAX_BUFFER_BYTES, `${what}: no WebGL buffer over ${MAX_BUFFER_BYTES >> 20} MiB`,
          `${buffers.count} buffers, the largest ${(buffers.maxBytes / 1048576).toFixed(2)} MiB`);
    // Drawn on demand: a page that redraws a million triangles in a loop keeps a software
    // rasterizer (and the machine) busy for nothing.
    await sleep(1500);
    const idleDraws = (await page.evaluate(() => window.__gl.draws)) - buffers.draws;
    check(idleDraws === 0, `${what}: no redraw while nothing changes`, `${idleDraws} draw calls in 1.5 s`);
    if (shot) {
      const lit = coverage(await canvasShot(page, shot));
      check(lit > 0.05, `${what}: the screenshot shows the mesh`, `${(100 * lit).toFixed(1)} % of the view`);
    }
    const errors = [...pageErrors, ...(last ? last.errors : [])];
    check(errors.length === 0, `${what}: no page errors`, errors.join('; '));
    await page.close();
    viewer.kill('SIGKILL');
  }
  await viewAll(chunks, streamTriangles, 'DIR (chunks)', null);
  await viewAll(ply, plyTriangles, 'MESH.ply', 'big-ply.png');
});
