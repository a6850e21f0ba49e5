// `tandem extract --neuroglancer DIR` opened in a real Neuroglancer (the npm package, bundled
// by bundle.mjs) in headless Debian Chromium: a tiny HTTP server on 127.0.0.1 (port 0, byte
// ranges as the sharded format needs) serves the bundle and the export; Neuroglancer shows
// the segmentation layer's meshes in the 3D view. Checks: the meshes load (from range reads
// of the shard), the 3D panel shows them in each segment's colour, a fine detail setting
// reads level 0 and a coarse one only the coarsest level (the byte ranges it reads), and
// neither picture has a crack (no background pixel enclosed by the closed surface's
// picture); views of a large label sheet that read every level-0 node or look from turned,
// low cameras become ready (viewer.isReady()) and show it. Saves the picture at
// build/viewer-test/neuroglancer.png (docs/img/neuroglancer.png is a copy of it): two exports
// side by side, as two segmentation layers.
// usage: node tests/neuroglancer/neuroglancer_browser_test.mjs BUILD_DIR
import { execFileSync } from 'node:child_process';
import fs from 'node:fs';
import http from 'node:http';
import path from 'node:path';
import zlib from 'node:zlib';
import { fileURLToPath } from 'node:url';
import { harness } from '../viewer/browser_harness.mjs';

const h = harness(process.argv[2]);
const { check, work, shots, bin, waitFor, sleep } = h;
const here = path.dirname(fileURLToPath(import.meta.url));
const root = path.resolve(here, '..', '..');
const COLORS = { 1: '#ff3030', 2: '#3070ff' };


if (!fs.existsSync(path.join(root, 'node_modules', 'neuroglancer', 'lib')) ||
    !fs.existsSync(path.join(root, 'node_modules', 'esbuild'))) {
  const why = 'node_modules/neuroglancer or esbuild is missing (bash deploy/install-web.sh)';
  if (process.env.CI === 'true') {
    console.error(`FAIL: ${why}`);
    process.exit(1);
  }
  console.log(`SKIP: ${why}`);
  process.exit(77);
}

// Serves "/" (the page), "/data/..." (the export) and every other path by its base name from
// the bundle folder (Neuroglancer asks for its workers and decoders relative to itself).
function serve(web, data, log) {
  const types = { '.js': 'text/javascript', '.css': 'text/css', '.wasm': 'application/wasm',
                  '.html': 'text/html' };
  const page = '<!doctype html><html><head><meta charset="utf-8">' +
    '<link rel="stylesheet" href="/ng/main.bundle.css"></head>' +
    '<body style="margin:0;overflow:hidden"><script type="module" src="/ng/main.bundle.js">' +
    '</script></body></html>';
  // Every page load reads afresh, so the reads tell which levels that load drew.
  const noStore = { 'Cache-Control': 'no-store' };
  const server = http.createServer((req, res) => {
    const url = new URL(req.url, 'http://127.0.0.1');
    if (url.pathname === '/') {
      res.writeHead(200, { 'Content-Type': 'text/html' });
      res.end(page);
      return;
    }
    let file;
    if (url.pathname.startsWith('/data/')) {
      file = path.resolve(data, decodeURIComponent(url.pathname.slice('/data/'.length)));
      if (!file.startsWith(data + path.sep) && file !== data) file = null;
    } else {
      file = path.join(web, path.basename(url.pathname));
    }
    if (!file || !fs.existsSync(file) || !fs.statSync(file).isFile()) {
      log.push({ path: url.pathname, status: 404 });
      res.writeHead(404);
      res.end();
      return;
    }
    const size = fs.statSync(file).size;
    const type = types[path.extname(file)] || 'application/octet-stream';
    const m = /^bytes=(\d*)-(\d*)$/.exec(req.headers.range || '');
    if (m) {
      let start = m[1] === '' ? size - Number(m[2]) : Number(m[1]);
      let end = m[1] === '' || m[2] === '' ? size - 1 : Math.min(Number(m[2]), size - 1);
      start = Math.max(0, start);
      if (start > end || start >= size) {
        res.writeHead(416, { 'Content-Range': `bytes */${size}` });
        res.end();
        return;
      }
      log.push({ path: url.pathname, status: 206, start, end });
      res.writeHead(206, { 'Content-Type': type, 'Content-Length': end - start + 1, ...noStore,
                           'Content-Range': `bytes ${start}-${end}/${size}`,
                           'Accept-Ranges': 'bytes' });
      fs.createReadStream(file, { start, end }).pipe(res);
      return;
    }
    log.push({ path: url.pathname, status: 200 });
    res.writeHead(200, { 'Content-Type': type, 'Content-Length': size, 'Accept-Ranges': 'bytes',
                         ...noStore });
    fs.createReadStream(file).pipe(res);
  });
  return new Promise((resolve) => server.listen(0, '127.0.0.1', () => resolve(server)));
}

// The PNG's pixels that are not the black background, how many lean to each segment's
// colour (its largest channel is the colour's), and the holes: background (black) pixels
// that cannot be reached from the picture's border without crossing the surface's picture
// where it is more than a pixel thick. A closed surface seen from outside has none; a crack
// between pieces shows as one. A pocket of the silhouette's outline that a one-pixel sliver
// (an edge seen edge-on) happens to close is not a crack: the flood passes such slivers.
function measure(file, PNG) {
  const png = PNG.sync.read(fs.readFileSync(file));
  const w = png.width, n = png.width * png.height;
  let lit = 0, red = 0, blue = 0;
  const surface = new Uint8Array(n);
  for (let p = 0; p < n; p++) {
    const [r, g, b] = [png.data[4 * p], png.data[4 * p + 1], png.data[4 * p + 2]];
    if (r + g + b <= 24) continue;
    lit++;
    if (r > 1.5 * Math.max(g, b)) red++;
    if (b > 1.5 * Math.max(r, g)) blue++;
    // The panel's labels are white or grey; shaded surface pixels keep their hue.
    surface[p] = Math.max(r, g, b) - Math.min(r, g, b) >= 40 ? 1 : 0;
  }
  // The surface less its one-pixel rim (a pixel stays if its four neighbours are surface).
  const thick = new Uint8Array(n);
  for (let p = 0; p < n; p++) {
    const x = p % w;
    thick[p] = surface[p] && x > 0 && x < w - 1 && p >= w && p < n - w && surface[p - 1] &&
      surface[p + 1] && surface[p - w] && surface[p + w] ? 1 : 0;
  }
  const reached = new Uint8Array(n);
  const stack = [];
  for (let p = 0; p < n; p++) {
    const x = p % w, y = (p - x) / w;
    if ((x === 0 || y === 0 || x === w - 1 || y === png.height - 1) && !thick[p]) {
      reached[p] = 1;
      stack.push(p);
    }
  }
  while (stack.length) {
    const p = stack.pop(), x = p % w;
    for (const q of [x > 0 ? p - 1 : -1, x < w - 1 ? p + 1 : -1, p - w, p + w]) {
      if (q >= 0 && q < n && !reached[q] && !thick[q]) {
        reached[q] = 1;
        stack.push(q);
      }
    }
  }
  // Only the background's black counts (a checkbox's white tick is enclosed too).
  let gaps = 0;
  for (let p = 0; p < n; p++) {
    const dark = png.data[4 * p] + png.data[4 * p + 1] + png.data[4 * p + 2] <= 24;
    gaps += dark && !reached[p] ? 1 : 0;
  }
  return { share: lit / n, red: red / n, blue: blue / n, gaps, size: `${w}x${png.height}` };
}

// Where each level's fragments of segment `id` lie in its shard (per level, one byte range
// per non-empty octree node), read the way Neuroglancer reads it: minishard index (gzip),
// manifest, fragments just before it. Only for a single-shard, single-minishard export.
function fragmentRanges(data, id) {
  const info = JSON.parse(fs.readFileSync(path.join(data, 'mesh', 'info'))).sharding;
  if (info.shard_bits !== 0 || info.minishard_bits !== 0) throw new Error('expected one shard');
  const shard = fs.readFileSync(path.join(data, 'mesh', '0.shard'));
  const u64 = (b, at) => Number(b.readBigUInt64LE(at));
  const index = zlib.gunzipSync(shard.subarray(16 + u64(shard, 0), 16 + u64(shard, 8)));
  const n = index.length / 24;
  let key = 0, end = 0;
  for (let i = 0; i < n; i++) {
    key += u64(index, 8 * i);
    const start = end + u64(index, 8 * (n + i)), size = u64(index, 8 * (2 * n + i));
    end = start + size;
    if (key !== id) continue;
    const m = shard.subarray(16 + start, 16 + end);
    const lods = m.readUInt32LE(24);
    let at = 28 + 16 * lods;
    const counts = [], sizes = [];
    for (let k = 0; k < lods; k++) counts.push(m.readUInt32LE(at + 4 * k));
    at += 4 * lods;
    for (let k = 0; k < lods; k++) {
      const level = [];
      for (let f = 0; f < counts[k]; f++) level.push(m.readUInt32LE(at + 12 * counts[k] + 4 * f));
      sizes.push(level);
      at += 16 * counts[k];
    }
    const total = sizes.flat().reduce((a, b) => a + b, 0);
    let from = 16 + start - total;
    return sizes.map((level) => level.map((bytes) => {
      const r = [from, from + bytes];
      from += bytes;
      return r;
    }).filter((r) => r[1] > r[0]));
  }
  throw new Error(`segment ${id} is not in the shard`);
}
// Per level, how many of its fragments a range read of the shard since `since` fetched.
const nodesRead = (log, ranges, since) => ranges.map((level) => level.filter(
  (r) => log.slice(since).some((q) => q.status === 206 && q.path.endsWith('.shard') &&
                                      q.start >= r[0] && q.start < r[1])).length);
// The levels of which some fragment was fetched since `since`.
const levelsRead = (log, ranges, since) => nodesRead(log, ranges, since)
  .map((n, k) => (n > 0 ? k : -1)).filter((k) => k >= 0);

await h.run(async () => {
  const { PNG } = await import('pngjs');
  const web = path.join(h.build, 'neuroglancer-web');
  execFileSync(process.execPath, [path.join(here, 'bundle.mjs'), web], { stdio: 'inherit' });
  check(fs.existsSync(path.join(web, 'main.bundle.js')), 'Neuroglancer bundled from node_modules');

  // Two nested spheres (iso 0 and 6 of the sphere field, a distance in voxels: radii 15.6 and
  // 9.6, segments 1 and 2), each at three levels of detail from sweeps at E0, 2 E0 and 4 E0.
  const volume = path.join(work, 'sphere.nrrd');
  execFileSync(bin('tandem'), ['generate', 'sphere', '--size', '40', '--out', volume]);
  const data = path.join(work, 'ng');
  execFileSync(bin('tandem'), ['extract', '--input', volume, '--iso', '0,6', '--error', '0.6',
                               '--out', path.join(work, 'sphere_{iso}.ply'), '--quiet',
                               '--neuroglancer', data, '--neuroglancer-lods', '3']);
  const shards = fs.readdirSync(path.join(data, 'mesh')).filter((n) => n.endsWith('.shard'));
  check(shards.length >= 1 && fs.existsSync(path.join(data, 'info')),
        'the export holds info, mesh/info and shard files', shards.join(' '));

  const log = [];
  const server = await serve(web, data, log);
  const base = `http://127.0.0.1:${server.address().port}`;
  try {
    const browser = await h.launch();
    const page = await browser.newPage({ viewport: { width: 640, height: 480 } });
    const errors = [];
    page.on('pageerror', (e) => errors.push(String(e)));
    const state = (segments, renderScale) => ({
      dimensions: undefined,
      layers: [{
        type: 'segmentation', name: 'tandem', source: `precomputed://${base}/data`,
        segments, segmentColors: COLORS, meshRenderScale: renderScale,
      }],
      layout: '3d', showAxisLines: false, showScaleBar: false, showDefaultAnnotations: false,
      projectionBackgroundColor: '#000000', selectedLayer: { visible: false },
    });
    // A fresh page each time (a hash change alone would keep the loaded levels).
    const open = async (segments, renderScale) => {
      await page.goto('about:blank');
      await page.goto(`${base}/#!${encodeURIComponent(JSON.stringify(state(segments, renderScale)))}`);
      await waitFor('the Neuroglancer viewer', () => page.evaluate(() => !!window.viewer), 60);
      // Ready: every visible layer's chunks loaded, the meshes drawn.
      await waitFor('the meshes to load',
                    () => page.evaluate(() => window.viewer.isReady()), 90);
      await sleep(500);
    };
    // A fresh page on a view state; with ready, once Neuroglancer has drawn it.
    const showView = async (view, ready = true) => {
      await page.goto('about:blank');
      await page.goto(`${base}/#!${encodeURIComponent(JSON.stringify(view))}`);
      await waitFor('the viewer', () => page.evaluate(() => !!window.viewer), 60);
      if (!ready) return;
      await waitFor('the sheet to load', () => page.evaluate(() => window.viewer.isReady()), 90);
      await sleep(500);
    };
    const shoot = async (name) => {
      const file = path.join(shots, name);
      await page.mouse.move(1, 1);  // off the panel: its hover widgets stay hidden
      const box = await page.locator('.neuroglancer-rendered-data-panel').first().boundingBox();
      await page.screenshot({ path: file, clip: box });
      return measure(file, PNG);
    };

    const ranges = fragmentRanges(data, 1);
    check(ranges.length === 3, 'segment 1 has three levels in the shard');
    let since = log.length;
    await open(['1'], 0.5);
    const fine = await shoot('neuroglancer-fine.png');
    const fineLevels = levelsRead(log, ranges, since);
    check(fineLevels.includes(0), 'a fine detail setting draws level 0', `read levels ${fineLevels}`);
    check(fine.share > 0.05, 'the 3D panel shows segment 1', `${(100 * fine.share).toFixed(1)} % lit`);
    check(fine.red > 0.6 * fine.share, "in segment 1's colour", `${(100 * fine.red).toFixed(1)} % red`);
    check(fine.gaps === 0, 'the finest level has no crack', `${fine.gaps} background pixels inside`);
    {
      // The detector itself: a 3 x 3 hole punched into the surface's middle is counted.
      const file = path.join(shots, 'neuroglancer-fine.png');
      const png = PNG.sync.read(fs.readFileSync(file));
      let sx = 0, sy = 0, m = 0;
      for (let p = 0; p < png.width * png.height; p++) {
        if (png.data[4 * p] > 100 && png.data[4 * p] > 1.5 * png.data[4 * p + 2]) {
          sx += p % png.width, sy += Math.floor(p / png.width), m++;
        }
      }
      const [cx, cy] = [Math.round(sx / m), Math.round(sy / m)];
      for (let dy = -1; dy <= 1; dy++) {
        for (let dx = -1; dx <= 1; dx++) {
          const at = 4 * ((cy + dy) * png.width + cx + dx);
          png.data.fill(0, at, at + 3);
        }
      }
      const punched = path.join(shots, 'neuroglancer-punched.png');
      fs.writeFileSync(punched, PNG.sync.write(png));
      check(measure(punched, PNG).gaps === 9, 'the crack check counts a punched hole');
    }
    check(log.some((r) => r.status === 206 && r.path.endsWith('.shard')),
          'Neuroglancer read the shard by byte ranges',
          `${log.filter((r) => r.status === 206).length} range reads`);
    check(errors.length === 0, 'no page errors', errors.join('; '));

    // The coarsest level: a detail cutoff that no level of this size fails.
    since = log.length;
    await open(['1'], 60000);  // Neuroglancer's largest detail cutoff is 65535
    const coarse = await shoot('neuroglancer-coarse.png');
    const coarseLevels = levelsRead(log, ranges, since);
    check(coarseLevels.includes(2) && !coarseLevels.includes(0),
          'a coarse detail setting draws level 2 and never fetches level 0',
          `read levels ${coarseLevels}`);
    check(coarse.share > 0.05 && coarse.red > 0.6 * coarse.share, 'the coarsest level shows segment 1');
    check(coarse.gaps === 0, 'the coarsest level has no crack', `${coarse.gaps} background pixels inside`);
    const a = PNG.sync.read(fs.readFileSync(path.join(shots, 'neuroglancer-fine.png')));
    const b = PNG.sync.read(fs.readFileSync(path.join(shots, 'neuroglancer-coarse.png')));
    let differ = 0;
    for (let i = 0; i < a.data.length; i += 4) {
      if (Math.abs(a.data[i] - b.data[i]) + Math.abs(a.data[i + 1] - b.data[i + 1]) > 30) differ++;
    }
    check(differ > 100, 'the level of detail switched (the pictures differ)', `${differ} pixels`);

    // Segment 2 (inside 1) alone, in its own colour: the second id's manifest found too, and
    // its own fragments: seen from the same default camera, its picture covers about
    // (9.6 / 15.6)^2 = 0.38 of segment 1's (the spheres' radii differ by 16 times E0).
    await open(['2'], 0.5);
    const inner = await shoot('neuroglancer-segment2.png');
    check(inner.share > 0.02 && inner.blue > 0.6 * inner.share, "segment 2 in its colour",
          `${(100 * inner.blue).toFixed(1)} % blue`);
    const area = inner.blue / fine.red;
    check(inner.size === fine.size && area > 0.3 && area < 0.47, 'segment 2 is the smaller sphere',
          `${(100 * inner.blue).toFixed(1)} % blue against ${(100 * fine.red).toFixed(1)} % red ` +
          `(${area.toFixed(2)}), panels ${inner.size} and ${fine.size}`);

    // A large segment seen close: label 1 fills a 128 x 128 x 40 label map below a wavy sheet
    // (open at the volume's border, so nothing but the black background lies behind it), nodes
    // of 8 voxels. The camera looks over the sheet from three sides: the near part is drawn at
    // a finer level than the far part in one frame, so levels meet on node faces all over the
    // picture; a crack there shows the background as an enclosed black pixel. The same views
    // of an export without skirts show such cracks (not each view: see below).
    const [nx, ny, nz] = [128, 128, 40];
    const labels = Buffer.alloc(nx * ny * nz);
    for (let z = 0; z < nz; z++) {
      for (let y = 0; y < ny; y++) {
        for (let x = 0; x < nx; x++) {
          const h = 20 + 5 * Math.sin(x / 7) * Math.cos(y / 9) + 3 * Math.sin((x + y) / 13);
          labels[(z * ny + y) * nx + x] = z < h ? 1 : 0;
        }
      }
    }
    const sheet = path.join(work, 'sheet.json');
    fs.writeFileSync(path.join(work, 'sheet.raw'), labels);
    fs.writeFileSync(sheet, JSON.stringify({
      dims: [nx, ny, nz], dtype: 'uint8', spacing: [1, 1, 1], origin: [0, 0, 0],
      byte_order: 'little', raw_file: 'sheet.raw', raw_bytes: labels.length }));
    const exports = {};
    for (const [name, extra] of [['skirted', []], ['cut', ['--neuroglancer-skirt', '0']]]) {
      const dir = path.join(work, `ng-sheet-${name}`);
      execFileSync(bin('tandem'), ['extract', '--input', sheet, '--labels', '--quiet',
                                   '--out', path.join(work, `sheet-${name}/`),
                                   '--neuroglancer', dir, '--neuroglancer-chunk', '8', ...extra]);
      fs.symlinkSync(dir, path.join(data, `sheet-${name}`));
      exports[name] = { ranges: fragmentRanges(dir, 1) };
    }
    // Rotations as Neuroglancer's [x, y, z, w]: `deg` about the unit axis `axis`, and a then b.
    const turn = (axis, deg) => {
      const h = (deg * Math.PI) / 360;
      return [...axis.map((a) => a * Math.sin(h)), Math.cos(h)];
    };
    const then = (b, a) => [
      b[3] * a[0] + b[0] * a[3] + b[1] * a[2] - b[2] * a[1],
      b[3] * a[1] - b[0] * a[2] + b[1] * a[3] + b[2] * a[0],
      b[3] * a[2] + b[0] * a[1] - b[1] * a[0] + b[2] * a[3],
      b[3] * a[3] - b[0] * a[0] - b[1] * a[1] - b[2] * a[2]];
    // Each view: the camera's turn, the detail setting, and the two levels it should mix.
    const views = [
      // Over the sheet (120 degrees about x), 48 voxels from the point looked at.
      { name: 'over', orientation: [0.866, 0, 0, 0.5], scale: 70, levels: [0, 2], lit: 0.8 },
      // Turned 35 degrees about the sheet's normal and tilted lower: other cell edges face
      // the camera, and the volume's far corner shows the background above the sheet.
      { name: 'turned', orientation: then(turn([0, 0, 1], 35), turn([1, 0, 0], 110)),
        scale: 70, levels: [0, 2], lit: 0.7 },
      // A coarser detail setting: level 1 near the camera, level 2 far from it.
      { name: 'coarser', orientation: then(turn([0, 0, 1], -50), turn([1, 0, 0], 125)),
        scale: 400, levels: [1, 2], lit: 0.8 },
    ];
    // Whether a view shows the cut export's cracks follows where, from its camera, the two
    // levels' cuts lie more than a pixel apart (levels 1 and 2 may nearly agree): the views
    // together must show some, so the check sees what the skirts close. That every face
    // between any two levels is closed, and open without skirts, neuroglancer_skirts_test checks.
    const cutGaps = [];
    let anyCut = false;
    for (const v of views) {
      const mixed = {};
      for (const name of ['skirted', 'cut']) {
        const view = {
          layers: [{ type: 'segmentation', name, source: `precomputed://${base}/data/sheet-${name}`,
                     segments: ['1'], segmentColors: COLORS, meshRenderScale: v.scale }],
          layout: '3d', showAxisLines: false, showScaleBar: false, showDefaultAnnotations: false,
          projectionBackgroundColor: '#000000', selectedLayer: { visible: false },
          position: [64, 64, 20], projectionScale: 40e-9, projectionOrientation: v.orientation,
        };
        since = log.length;
        await showView(view);
        mixed[name] = { picture: await shoot(`neuroglancer-${v.name}-${name}.png`),
                        nodes: nodesRead(log, exports[name].ranges, since),
                        total: exports[name].ranges.map((l) => l.length) };
      }
      const { picture: sheetPicture, nodes, total } = mixed.skirted;
      const [near, far] = v.levels;
      if (v.name === 'over') {
        check(total[0] > 100 && total[1] > 20 && total[2] > 8,
              'the large segment is an octree of many nodes per level', `${total} nodes`);
      }
      check(nodes[near] > 0 && nodes[near] < total[near] / 4 && nodes[far] > 0 &&
            nodes.slice(0, near).every((n) => n === 0),
            `${v.name}: one frame draws level ${near} near the camera and level ${far} far from it`,
            `fetched ${nodes} of ${total} nodes per level`);
      check(sheetPicture.share > v.lit && sheetPicture.red > 0.8 * sheetPicture.share,
            `${v.name}: the sheet fills the view`, `${(100 * sheetPicture.share).toFixed(1)} % lit`);
      cutGaps.push(`${v.name} ${mixed.cut.picture.gaps}`);
      anyCut = anyCut || mixed.cut.picture.gaps > 0;
      check(sheetPicture.gaps === 0, `${v.name}: with skirts, no crack where the levels meet`,
            `${sheetPicture.gaps} background pixels inside`);
    }
    check(anyCut, 'cut without skirts, the levels leave cracks the check sees',
          `background pixels inside per view: ${cutGaps.join(', ')}`);
    // Views that must become ready: Neuroglancer reports ready only once every node its walk
    // wants is on the GPU, and a node whose fragment fails to decode is never retried. A
    // fragment holding corners no triangle used was such a node (near the sheet's far corner),
    // wanted by a fine setting that reads every level-0 node and by the turned, low camera.
    const readyViews = [
      { name: 'every-node', orientation: [0.866, 0, 0, 0.5], scale: 1, projection: 1.6e-7,
        every: true, lit: 0.2 },
      { name: 'turned-low', orientation: then(turn([0, 0, 1], -80), turn([1, 0, 0], 105)),
        scale: 70 },
      { name: 'turned-back', orientation: then(turn([0, 0, 1], -120), turn([1, 0, 0], 115)),
        scale: 70 },
      { name: 'turned-round', orientation: then(turn([0, 0, 1], 260), turn([1, 0, 0], 120)),
        scale: 70 },
    ];
    for (const v of readyViews) {
      const view = {
        layers: [{ type: 'segmentation', name: 'skirted',
                   source: `precomputed://${base}/data/sheet-skirted`, segments: ['1'],
                   segmentColors: COLORS, meshRenderScale: v.scale }],
        layout: '3d', showAxisLines: false, showScaleBar: false, showDefaultAnnotations: false,
        projectionBackgroundColor: '#000000', selectedLayer: { visible: false },
        position: [64, 64, 20], projectionScale: v.projection || 40e-9,
        projectionOrientation: v.orientation,
      };
      since = log.length;
      await showView(view, false);
      const began = Date.now();
      const ready = await waitFor('the sheet to load',
                                  () => page.evaluate(() => window.viewer.isReady()), 60)
        .catch(() => false);
      const nodes = nodesRead(log, exports.skirted.ranges, since);
      check(ready, `${v.name}: Neuroglancer reports the view ready`,
            `${ready ? ((Date.now() - began) / 1000).toFixed(1) + ' s' : 'not within 60 s'}, ` +
            `fetched ${nodes} nodes per level`);
      if (v.every) {
        const total = exports.skirted.ranges[0].length;
        check(nodes[0] === total, `${v.name}: a fine setting reads every level-0 node`,
              `${nodes[0]} of ${total}`);
      }
      await sleep(500);
      const picture = await shoot(`neuroglancer-${v.name}.png`);
      check(picture.share > (v.lit || 0.5) && picture.red > 0.8 * picture.share &&
            picture.gaps === 0, `${v.name}: the sheet shows, without a crack`,
            `${(100 * picture.share).toFixed(1)} % lit, ${picture.gaps} background pixels inside`);
    }
    // Cameras from a sweep of turns and tilts that each showed background through a crack
    // before: a level's cut lying just above a cell face (its strip must go on in the cell
    // below) or a level's surface lying in a cell face (another level's strip must reach past
    // it). Drawn with skirts only; each view mixes levels as the three above do.
    for (const [about, tilt] of [[-170, 130], [90, 125], [-170, 140]]) {
      const view = {
        layers: [{ type: 'segmentation', name: 'skirted', segments: ['1'], segmentColors: COLORS,
                   source: `precomputed://${base}/data/sheet-skirted`, meshRenderScale: 70 }],
        layout: '3d', showAxisLines: false, showScaleBar: false, showDefaultAnnotations: false,
        projectionBackgroundColor: '#000000', selectedLayer: { visible: false },
        position: [64, 64, 20], projectionScale: 40e-9,
        projectionOrientation: then(turn([0, 0, 1], about), turn([1, 0, 0], tilt)),
      };
      since = log.length;
      await showView(view);
      const picture = await shoot(`neuroglancer-sweep${about}-${tilt}.png`);
      const nodes = nodesRead(log, exports.skirted.ranges, since);
      check(nodes.filter((n) => n > 0).length >= 2 && picture.share > 0.7,
            `turned ${about}, tilted ${tilt}: the sheet fills the view at two levels or more`,
            `fetched ${nodes} nodes per level, ${(100 * picture.share).toFixed(1)} % lit`);
      check(picture.gaps === 0, `turned ${about}, tilted ${tilt}: no crack where the levels meet`,
            `${picture.gaps} background pixels inside`);
    }
    // The picture for the docs (docs/img/neuroglancer.png): a gyroid ball and two linked
    // tori beside it, two exports as two segmentation layers, each segment in its colour.
    const layers = [];
    for (const [shape, x, color] of [['gyroid', 0, '#e8a33d'], ['link', 52, '#3db4e8']]) {
      const v = path.join(work, `${shape}.nrrd`), dir = path.join(work, `ng-${shape}`);
      execFileSync(bin('tandem'), ['generate', shape, '--size', '48', '--origin', `${x},0,0`,
                                   '--out', v]);
      execFileSync(bin('tandem'), ['extract', '--input', v, '--iso', '0', '--quiet',
                                   '--out', path.join(work, `${shape}.ply`), '--neuroglancer', dir]);
      fs.symlinkSync(dir, path.join(data, shape));
      layers.push({ type: 'segmentation', name: shape, source: `precomputed://${base}/data/${shape}`,
                    segments: ['1'], segmentColors: { 1: color } });
    }
    const picture = { layers, layout: '3d', showAxisLines: false, showScaleBar: false,
                      projectionBackgroundColor: '#000000', selectedLayer: { visible: false },
                      showDefaultAnnotations: false,
                      projectionOrientation: [0.12, 0.2, 0, 0.972], projectionScale: 8.5e-8,
                      position: [44, 24, 24] };
    await page.goto('about:blank');
    await page.goto(`${base}/#!${encodeURIComponent(JSON.stringify(picture))}`);
    await waitFor('the viewer', () => page.evaluate(() => !!window.viewer), 60);
    await waitFor('both layers to load', () => page.evaluate(() => window.viewer.isReady()), 90);
    await page.addStyleTag({ content: '.neuroglancer-display-dimensions-widget { display: none }' });
    await sleep(500);
    const both = await shoot('neuroglancer.png');
    check(both.share > 0.1, 'two exports side by side in the 3D view', `${(100 * both.share).toFixed(1)} % lit`);
    check(errors.length === 0, 'no page errors at the end', errors.join('; '));
  } finally {
    server.close();
  }
});
