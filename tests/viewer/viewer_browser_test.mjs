// The live viewer in a real browser: headless Debian Chromium (driven by playwright-core)
// loads the page of `tandem-client stream --view` against the real tandem-server on
// 127.0.0.1 and looks at the 3D view (the canvas, cropped: share of non-background pixels,
// their colours) and at the page's state while the scan is still running. The test holds
// the pace: the client follows a folder of numbered TIFF slices that the test fills, so the
// scan cannot end before the test has looked (no wall-clock guess); and its metrics file is
// a named pipe, so the client cannot end before the test has seen the finishing state.
//   A. unsealed, two iso-values, depth unknown: both surfaces' previews drawn mid-scan, each
//      in its own colour; the bar at slices meshed / slices on disk; after the last slice a
//      finishing state with an estimate; at the end both final meshes in their colours and
//      a metrics row per surface.
//   B. sealed, known depth: chunks and band drawn mid-scan, the bar at slices meshed /
//      depth, a vertex on a chunk border with one normal in every chunk (read from the
//      page's geometry), the mesh grows, the final counts equal the final metrics, clipping,
//      reset, a watcher's page, a reload; `tandem view` of a file, a Draco GLB, a folder of
//      chunks behind a token, a busy port.
//   C. sealed, two iso-values: each surface's chunks in its colour, normals per surface.
// Every wait is bounded (generously: a loaded 2-core machine); children are killed at the end.
//   node tests/viewer/viewer_browser_test.mjs BUILD_DIR
// Exit 0: passed; 1: failed; 77: skipped (no Chromium or node_modules, outside CI).
import { spawnSync } from 'node:child_process';
import fs from 'node:fs';
import path from 'node:path';
import { harness } from './browser_harness.mjs';

const { work, bin, check, start, sleep, waitFor, urlIn, startServer, launch, canvasShot, pageShot,
        pixels, coverage, chromaOf, chromaDistance, copySlices, run } = harness(process.argv[2]);

// Bound of every wait for the page or a child, in seconds: what it waits for takes a few
// seconds; the bound only ends a test that is stuck.
const LONG = 240;
const DEPTH = 96;  // slices of the scan

// What the page shows, in one call.
const viewOf = (page) => page.evaluate(() => {
  const v = window.tandemView;
  return v && v.state && {
    drawn: v.trianglesDrawn, chunks: v.chunksDrawn, band: v.bandTriangles, sealed: v.sealedTriangles,
    finished: v.finished, errors: v.errors, rendered: v.rendered, frames: v.frames,
    shown: document.getElementById('drawn').textContent, state: v.state,
    surfaces: v.surfaces(), progress: v.progress(), statuses: window.__tandemTest.statuses,
  };
});

// Normals of the chunks drawn, against the same normals computed here from every chunk's
// triangles (area-weighted sums by surface and global id): `shared` vertices lie in two or
// more chunks; `spread` is the largest difference between one vertex's normals in its
// chunks, `error` the largest from the sum over all chunks drawn.
const chunkNormals = (page) => page.evaluate(() => {
  const sums = new Map(), seen = new Map();
  const meshes = window.__tandemTest.meshes().filter((m) => m.kind === 'chunk');
  for (const m of meshes) {
    const p = m.geometry.attributes.position.array, index = m.geometry.index.array;
    for (let t = 0; t < index.length; t += 3) {
      const [a, b, c] = [0, 1, 2].map((k) => 3 * index[t + k]);
      const u = [p[b] - p[a], p[b + 1] - p[a + 1], p[b + 2] - p[a + 2]];
      const v = [p[c] - p[a], p[c + 1] - p[a + 1], p[c + 2] - p[a + 2]];
      const n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
      for (let k = 0; k < 3; k++) {
        const key = `${m.surface}:${m.ids[index[t + k]]}`;
        const s = sums.get(key) || [0, 0, 0];
        sums.set(key, [s[0] + n[0], s[1] + n[1], s[2] + n[2]]);
      }
    }
    const normal = m.geometry.attributes.normal.array;
    for (let i = 0; i < m.ids.length; i++) {
      const key = `${m.surface}:${m.ids[i]}`;
      if (!seen.has(key)) seen.set(key, []);
      seen.get(key).push({ chunk: m.chunk, n: [normal[3 * i], normal[3 * i + 1], normal[3 * i + 2]] });
    }
  }
  let shared = 0, spread = 0, error = 0;
  const distance = (a, b) => Math.hypot(a[0] - b[0], a[1] - b[1], a[2] - b[2]);
  for (const [key, list] of seen) {
    const s = sums.get(key), length = Math.hypot(...s) || 1;
    const expected = s.map((x) => x / length);
    if (new Set(list.map((o) => o.chunk)).size > 1) shared++;
    for (const o of list) {
      spread = Math.max(spread, distance(o.n, list[0].n));
      error = Math.max(error, distance(o.n, expected));
    }
  }
  return { vertices: seen.size, shared, spread, error, meshes: meshes.length };
});

await run(async () => {
  const volume = path.join(work, 'gyroid.json');
  const staged = path.join(work, 'staged');
  for (const out of [volume, staged]) {
    const gen = spawnSync(bin('tandem'), ['generate', 'gyroid', '--size', String(DEPTH), '--out', out,
                                          ...(out === staged ? ['--series', 'tiff'] : [])]);
    if (gen.status !== 0) throw new Error(`tandem generate: ${gen.stderr}`);
  }
  // Band previews up to 4x the chunks' bytes (default: a quarter, which allows only a few
  // over a short scan), so that the live view has a fresh band to show; streams held by the
  // test stay open however long it looks.
  const address = await startServer(['--max-band-bytes-share', '4', '--idle-timeout-seconds', '900']);
  const browser = await launch();
  const pageErrors = [];
  async function openPage(client, what) {
    const url = await waitFor(`${what}: the viewer address`, () => urlIn(client), LONG);
    const page = await browser.newPage({ viewport: { width: 960, height: 640 } });
    page.on('pageerror', (e) => pageErrors.push(`${what}: ${e.message}`));
    await page.goto(url);
    return page;
  }
  // The scan in `scan` grows (4 slices at a time, from `count`) until the page shows what
  // `ready` wants, with at least `min` slices in and at most `max`; then the test holds it
  // there until the server has meshed every slice on disk. Returns the slices in.
  async function feedUntil(page, scan, count, min, max, ready, what) {
    const until = Date.now() + LONG * 1000;
    for (;;) {
      const v = await viewOf(page);
      if (count >= min && v && ready(v)) break;
      if (Date.now() > until) throw new Error(`timed out after ${LONG} s feeding slices for ${what}: ${JSON.stringify(v && { ...v, state: undefined })}`);
      if (count < max) count = copySlices(staged, scan, count, count + 4);
      await sleep(250);
    }
    await waitFor(`${what}: the server meshes the ${count} slices on disk`, async () => {
      const v = await viewOf(page);
      return v.state.slices_meshed === count;
    }, LONG);
    return count;
  }
  // Does `act` (a click, a scroll) and waits until the page has drawn a frame since and has
  // none waiting: what a screenshot then shows is the result of `act`.
  async function afterFrame(page, act, what) {
    const before = (await viewOf(page)).frames;
    await act();
    await waitFor(what, async () => {
      const v = await viewOf(page);
      return v.rendered && v.frames > before;
    }, LONG);
  }
  // Shows only surface `only` (the legend's boxes; -1 = all) and waits for the frame.
  async function showOnly(page, only) {
    const n = (await viewOf(page)).surfaces.length;
    await afterFrame(page, async () => {
      for (let i = 0; i < n; i++) {
        await page.setChecked(`#legend label.surface[data-surface="${i}"] input`, only < 0 || i === only);
      }
    }, 'the page to draw the surfaces asked for');
  }
  // Each surface alone, in a canvas screenshot: its pixels' colour is its own `key` colour
  // (sealedColor or bandColor), nearer to it than to any other surface's.
  async function surfaceColours(page, key, name) {
    const surfaces = (await viewOf(page)).surfaces;
    const out = [];
    for (let i = 0; i < surfaces.length; i++) {
      await showOnly(page, i);
      const p = pixels(await canvasShot(page, `${name}-surface${i}.png`));
      const own = chromaDistance(p.chroma, chromaOf(surfaces[i][key]));
      const others = Math.min(...surfaces.filter((_, j) => j !== i).map((s) => chromaDistance(p.chroma, chromaOf(s[key]))));
      out.push({ share: p.share, own, others, mean: p.mean.map(Math.round) });
    }
    await showOnly(page, -1);
    return out;
  }
  const describe = (v) => JSON.stringify({ drawn: v.drawn, chunks: v.chunks, band: v.band, finished: v.finished,
                                           meshed: v.state.slices_meshed, progress: v.progress });

  // --- A. Unsealed, two surfaces, a scan of unknown depth. ---------------------------------
  const scanA = path.join(work, 'scanA');
  fs.mkdirSync(scanA);
  let inA = copySlices(staged, scanA, 0, 8);
  const metricsA = path.join(work, 'two.metrics.json');
  if (spawnSync('mkfifo', [metricsA]).status !== 0) throw new Error('mkfifo failed');
  const two = start('tandem-client', [
    'stream', '--server', address, '--input', scanA, '--follow', '--settle', '900', '--done-file', 'DONE',
    '--iso', '0,2', '--error', '0.05', '--out', path.join(work, 'two_{iso}.ply'), '--metrics', metricsA,
    '--view', '127.0.0.1:0', '--view-linger', String(LONG)]);
  const pageA = await openPage(two, 'unsealed');
  inA = await feedUntil(pageA, scanA, inA, 32, DEPTH - 8,
                        (v) => v.surfaces.length === 2 && v.surfaces.every((s) => s.bandTriangles > 0), 'previews');
  const midA = await viewOf(pageA);
  check(!midA.finished && two.exitCode === null && midA.progress.phase === 'live',
        'unsealed: the scan is still running (the test holds it)', `${inA} of ${DEPTH} slices on disk, ${describe(midA)}`);
  check(midA.chunks === 0 && midA.surfaces.every((s) => s.bandTriangles > 0),
        'unsealed: both surfaces are drawn mid-scan from the previews',
        JSON.stringify(midA.surfaces.map((s) => [s.label, s.bandTriangles])));
  check(midA.progress.value === inA && midA.progress.max === inA && midA.state.slices_on_disk === inA,
        'unsealed: the bar stands at slices meshed / slices on disk', JSON.stringify(midA.progress));
  const liveA = coverage(await canvasShot(pageA, 'live-unsealed.png'));
  await pageShot(pageA, 'page-live-unsealed.png');
  check(liveA > 0.01, 'unsealed: the live canvas shows the mesh', `${(100 * liveA).toFixed(1)} % of the view`);
  const previewColours = await surfaceColours(pageA, 'bandColor', 'live-unsealed');
  check(previewColours.every((c) => c.share > 0.002 && c.own < c.others),
        'unsealed: each surface is drawn in its own colour mid-scan', JSON.stringify(previewColours));

  // The rest of the scan, and its end: the client stops at its metrics (a named pipe) until
  // the test has seen the finishing state.
  copySlices(staged, scanA, inA, DEPTH);
  fs.writeFileSync(path.join(scanA, 'DONE'), '');
  const finishing = await waitFor('the finishing state', async () => {
    const v = await viewOf(pageA);
    return v.progress.phase === 'finishing' ? v : null;
  }, LONG);
  check(/every slice is in: simplifying and encoding [\d,]+ triangles, (about .* left|.* so far)/.test(finishing.progress.text) &&
        finishing.state.finishing.triangles > 0 && finishing.state.finishing.estimate_s > 0,
        'unsealed: after the last slice the page shows the finishing state with an estimate', finishing.progress.text);
  await pageShot(pageA, 'page-finishing.png');
  check(finishing.progress.value === DEPTH && finishing.progress.max === DEPTH,
        'unsealed: the bar is full while finishing', JSON.stringify(finishing.progress));
  const metricsText = await Promise.race([fs.promises.readFile(metricsA, 'utf8'), sleep(LONG * 1000).then(() => null)]);
  if (metricsText === null) throw new Error(`the client never wrote its metrics: ${two.err}`);
  const twoMetrics = JSON.parse(metricsText);
  const endA = await waitFor('the unsealed stream to end', async () => {
    const v = await viewOf(pageA);
    return v.finished && v.surfaces.every((s, i) => s.bandTriangles === twoMetrics[i].triangles_final) ? v : null;
  }, LONG).catch(async () => viewOf(pageA));
  const finals = twoMetrics.map((m) => m.triangles_final);
  check(endA.finished && endA.drawn === finals[0] + finals[1] && finals.every((n) => n > 0),
        'unsealed: the end view draws both final meshes', `${endA.drawn} drawn, final ${finals.join(' + ')}`);
  const statuses = endA.statuses.join(' > ');
  check(/live > finishing > finished$/.test(statuses), 'unsealed: live, then finishing, then finished', statuses);
  check(/^finished .* after the last slice$/.test(endA.progress.text), 'unsealed: the time the end took', endA.progress.text);
  const rows = await pageA.evaluate(() => ({
    heads: [...document.querySelectorAll('#metrics tr.surface-head')].map((r) => r.textContent.trim()),
    first: document.getElementById('metric-triangles_final')?.textContent,
    second: document.getElementById('metric-triangles_final-1')?.textContent,
  }));
  check(rows.heads.join(',') === 'iso 0,iso 2' && rows.first === String(finals[0]) && rows.second === String(finals[1]),
        'unsealed: the final metrics table has rows for each surface', JSON.stringify(rows));
  await pageShot(pageA, 'page-final-unsealed.png');
  const finalColours = await surfaceColours(pageA, 'sealedColor', 'final-unsealed');
  check(finalColours.every((c) => c.share > 0.01 && c.own < c.others),
        'unsealed: each final surface is drawn in its own colour', JSON.stringify(finalColours));
  two.kill('SIGINT');  // Ctrl-C: the page has been seen, the client stops lingering
  await Promise.race([two.exited, sleep(LONG * 1000)]);
  check(two.code === 0 && fs.existsSync(path.join(work, 'two_0.ply')) && fs.existsSync(path.join(work, 'two_2.ply')),
        'unsealed: the client wrote both surfaces and quits on Ctrl-C', `exit ${two.code}: ${two.err.slice(-300)}`);

  // --- B. Sealed, known depth. -----------------------------------------------------------
  const scanB = path.join(work, 'scanB');
  fs.mkdirSync(scanB);
  let inB = copySlices(staged, scanB, 0, 8);
  const client = start('tandem-client', [
    'stream', '--server', address, '--input', scanB, '--follow', '--expect-slices', String(DEPTH),
    '--settle', '900', '--iso', '0', '--error', '0.05', '--seal', '--out', path.join(work, 'gyroid.ply'),
    '--chunks', path.join(work, 'chunks'), '--metrics', path.join(work, 'gyroid.json.metrics'),
    '--view', '127.0.0.1:0', '--view-linger', String(LONG)]);
  const page = await openPage(client, 'sealed');
  inB = await feedUntil(page, scanB, inB, 40, DEPTH - 8, (v) => v.chunks >= 2 && v.band > 0, 'chunks and band');
  const early = await viewOf(page);
  check(!early.finished && client.exitCode === null && early.chunks >= 2 && early.band > 0,
        'sealed: chunks and the band are drawn while the scan still runs', describe(early));
  const fill = await page.evaluate(() => parseFloat(document.getElementById('fill').style.width));
  check(early.progress.value === inB && early.progress.max === DEPTH && Math.abs(fill - 100 * inB / DEPTH) < 0.01,
        'sealed: the bar stands at slices meshed / depth', `${JSON.stringify(early.progress)}, ${fill} %`);
  const liveCoverage = coverage(await canvasShot(page, 'live.png'));
  await pageShot(page, 'page-live.png');
  check(liveCoverage > 0.01, 'sealed: the live canvas shows the mesh', `${(100 * liveCoverage).toFixed(1)} % of the view`);
  const liveNormals = await chunkNormals(page);
  check(liveNormals.shared > 0 && liveNormals.spread < 1e-6 && liveNormals.error < 1e-3,
        'sealed: a vertex on a chunk border has one normal in all its chunks, mid-scan', JSON.stringify(liveNormals));

  // A watcher joining mid-scan (tandem-client watch --view) draws the chunks so far while the
  // scan is still held, its bar over the depth the session announces.
  const session = (client.err.match(/session ([0-9a-f]{32})/) || [])[1];
  const liveWatcher = start('tandem-client', ['watch', '--server', address, '--session', session,
                                              '--out', path.join(work, 'watched.ply'),
                                              '--view', '127.0.0.1:0', '--view-linger', String(LONG)]);
  const liveWatchPage = await openPage(liveWatcher, 'watcher mid-scan');
  const watchedLive = await waitFor('the watcher to draw the chunks so far', async () => {
    const v = await viewOf(liveWatchPage);
    return v && v.chunks >= early.chunks && v.rendered ? v : null;
  }, LONG);
  const watchedCoverage = coverage(await canvasShot(liveWatchPage, 'live-watcher.png'));
  check(!watchedLive.finished && client.exitCode === null && watchedLive.sealed > 0 && watchedCoverage > 0.01 &&
        watchedLive.progress.max === DEPTH && watchedLive.progress.value === inB,
        'watch --view joining mid-scan draws the chunks so far, the bar over the depth',
        `${describe(watchedLive)}, ${(100 * watchedCoverage).toFixed(1)} % of the view`);
  await liveWatchPage.close();

  copySlices(staged, scanB, inB, DEPTH);
  const done = await waitFor('the end of the stream', async () => {
    const v = await viewOf(page);
    return v && v.finished && v.chunks === v.state.chunks ? v : null;
  }, LONG);
  // The sealed part only grows. (All drawn, chunks plus band, need not: the band holds the
  // front's triangles not simplified yet, so near the end it can exceed the final count.)
  check(done.sealed > early.sealed, 'sealed: the mesh grows', `${early.sealed} then ${done.sealed} sealed triangles`);
  await waitFor('the client to write its metrics', () => fs.existsSync(path.join(work, 'gyroid.json.metrics')), LONG);
  const metrics = JSON.parse(fs.readFileSync(path.join(work, 'gyroid.json.metrics'), 'utf8'));
  check(done.drawn === metrics.triangles_final, 'sealed: triangles drawn = the final metrics', `${done.drawn} vs ${metrics.triangles_final}`);
  check(done.shown === metrics.triangles_final.toLocaleString('en-US'), 'sealed: the panel shows that count', done.shown);
  const shownFinal = await page.evaluate(() => document.getElementById('metric-triangles_final')?.textContent);
  check(shownFinal === String(metrics.triangles_final), 'sealed: the final metrics table shows triangles_final', shownFinal);
  check(done.statuses.includes('finishing') || done.state.finishing !== null,
        'sealed: the end had its finishing state', `${done.statuses.join(' > ')}; ${JSON.stringify(done.state.finishing)}`);
  const endNormals = await chunkNormals(page);
  check(endNormals.shared > liveNormals.shared && endNormals.spread < 1e-6 && endNormals.error < 1e-3,
        'sealed: every chunk border has one normal per vertex at the end', JSON.stringify(endNormals));
  await waitFor('the final frame', async () => (await viewOf(page)).rendered, LONG);
  const finalCoverage = coverage(await canvasShot(page, 'final.png'));
  await pageShot(page, 'page-final.png');
  check(finalCoverage > 0.05, 'sealed: the final canvas shows the mesh', `${(100 * finalCoverage).toFixed(1)} % of the view`);

  // The clipping plane cuts the mesh (half of it gone), reset view brings back the framing.
  await afterFrame(page, () => page.check('#clip'), 'the clipped frame');
  const clipped = coverage(await canvasShot(page, 'clipped.png'));
  await pageShot(page, 'page-clipped.png');
  check(clipped > 0.01 && clipped < 0.85 * finalCoverage, 'the clipping plane cuts the mesh',
        `${(100 * clipped).toFixed(1)} % of the view against ${(100 * finalCoverage).toFixed(1)} %`);
  await afterFrame(page, () => page.uncheck('#clip'), 'the unclipped frame');
  await page.mouse.move(700, 300);
  await afterFrame(page, () => page.mouse.wheel(0, 2000), 'the zoomed-out frame');
  await afterFrame(page, () => page.click('#reset'), 'the reset frame');
  const reset = coverage(await canvasShot(page, 'reset.png'));
  check(Math.abs(reset - finalCoverage) < 0.2 * finalCoverage, 'reset view frames the mesh again',
        `${(100 * reset).toFixed(1)} % of the view`);

  // A late viewer of the finished session (tandem-client view: the watch RPC) draws it all,
  // its bar over the depth the session announces.
  // Its token from the environment: the page's own files need it too, and the browser
  // gets them through the cookie the printed address gives it.
  const watcher = start('tandem-client', ['view', '--server', address, '--session', session,
                                          '--view', '127.0.0.1:0', '--view-linger', String(LONG)],
                        { TANDEM_VIEW_TOKEN: 'w4tch' });
  const watchUrl = await waitFor('tandem-client view', () => urlIn(watcher), LONG);
  check(watchUrl.includes('?token=w4tch'), 'the token from $TANDEM_VIEW_TOKEN', watchUrl);
  const script = await fetch(watchUrl.replace(/\?token=.*/, 'viewer.js'));
  check(script.status === 401, "the page's files need the token too", `HTTP ${script.status}`);
  const watchPage = await browser.newPage({ viewport: { width: 960, height: 640 } });
  watchPage.on('pageerror', (e) => pageErrors.push(`watcher: ${e.message}`));
  await watchPage.goto(watchUrl);
  const watched = await waitFor('the watched session drawn', async () => {
    const v = await viewOf(watchPage);
    return v && v.finished && v.chunks === v.state.chunks ? v : null;
  }, LONG);
  check(watched.drawn === metrics.triangles_final && watched.progress.max === DEPTH,
        'tandem-client view draws the watched session', `${watched.drawn} triangles, ${JSON.stringify(watched.progress)}`);
  await watchPage.close();

  // A reload (or a late browser) catches up from the immutable chunks.
  await page.reload();
  const again = await waitFor('the reloaded page to catch up', async () => {
    const v = await viewOf(page);
    return v && v.finished && v.drawn === metrics.triangles_final ? v : null;
  }, LONG);
  check(again.chunks === done.chunks, 'the reloaded page draws every chunk again', `${again.chunks} chunks`);
  const reloadedNormals = await chunkNormals(page);
  check(reloadedNormals.spread < 1e-6 && reloadedNormals.error < 1e-3, 'the reloaded page has the same normals',
        JSON.stringify(reloadedNormals));

  // --- C. Sealed, two surfaces: each one's chunks in its colour, normals per surface. ------
  // Not simplified: each surface is several chunks (a chunk holds at most 32,768 triangles
  // sealed between two slices), however fast the stream runs.
  const sealedTwo = start('tandem-client', [
    'stream', '--server', address, '--input', volume, '--iso', '0,2', '--no-simplify', '--seal',
    '--out', path.join(work, 'sealed_{iso}.ply'), '--metrics', path.join(work, 'sealed-two.json'),
    '--view', '127.0.0.1:0', '--view-linger', String(LONG)]);
  const pageC = await openPage(sealedTwo, 'sealed, two surfaces');
  const endC = await waitFor('the sealed two-surface stream to end', async () => {
    const v = await viewOf(pageC);
    return v && v.finished && v.chunks === v.state.chunks && v.rendered ? v : null;
  }, LONG);
  const metricsC = JSON.parse(fs.readFileSync(path.join(work, 'sealed-two.json'), 'utf8'));
  const bySurface = [0, 1].map((i) => endC.state.chunk_surfaces.filter((s) => s === i).length);
  check(endC.surfaces.map((s) => s.chunks).join() === bySurface.join() && bySurface.every((n) => n > 0) &&
        endC.surfaces.every((s, i) => s.sealedTriangles === metricsC[i].triangles_final),
        'sealed, two surfaces: each surface draws its own chunks', JSON.stringify(endC.surfaces.map((s) => [s.label, s.chunks, s.sealedTriangles])));
  const colourC = await surfaceColours(pageC, 'sealedColor', 'sealed-two');
  check(colourC.every((c) => c.share > 0.01 && c.own < c.others),
        "sealed, two surfaces: each surface's chunks in its own colour", JSON.stringify(colourC));
  const normalsC = await chunkNormals(pageC);
  check(normalsC.shared > 0 && normalsC.spread < 1e-6 && normalsC.error < 1e-3,
        'sealed, two surfaces: one normal per vertex and surface across chunks', JSON.stringify(normalsC));

  // tandem view: a finished file, and a folder of chunks behind a token.
  const plyView = start('tandem', ['view', path.join(work, 'gyroid.ply'), '--view', '127.0.0.1:0', '--linger', String(LONG)]);
  const plyUrl = await waitFor('tandem view MESH', () => urlIn(plyView), LONG);
  await page.goto(plyUrl);
  const ply = await waitFor('the PLY file drawn', async () => {
    const v = await viewOf(page);
    return v && v.drawn > 0 ? v : null;
  }, LONG);
  check(ply.drawn === metrics.triangles_final, 'tandem view MESH.ply draws the final mesh', `${ply.drawn} triangles`);
  const port = plyUrl.match(/:(\d+)\//)[1];
  const busy = start('tandem', ['view', path.join(work, 'gyroid.ply'), '--view', `127.0.0.1:${port}`, '--linger', '1']);
  await busy.exited;
  check(busy.code !== 0 && busy.err.includes(port), 'a second viewer on a busy port fails naming the port', busy.err.trim());

  // A Draco-compressed GLB (--glb-draco): three.js's GLTFLoader with its Draco decoder, an
  // independent reader, draws the triangles tandem extract reported.
  const glb = path.join(work, 'gyroid.draco.glb');
  const made = spawnSync(bin('tandem'), ['extract', '--input', volume, '--iso', '0', '--error', '0.05',
                                         '--out', glb, '--glb-draco', '--metrics', glb + '.json']);
  if (made.status !== 0) throw new Error(`tandem extract --glb-draco: ${made.stderr}`);
  const glbTriangles = JSON.parse(fs.readFileSync(glb + '.json', 'utf8')).triangles_final;
  const glbView = start('tandem', ['view', glb, '--view', '127.0.0.1:0', '--linger', String(LONG)]);
  await page.goto(await waitFor('tandem view GLB', () => urlIn(glbView), LONG));
  const drawnGlb = await waitFor('the Draco GLB drawn', async () => {
    const v = await viewOf(page);
    return v && v.drawn > 0 ? v : null;
  }, LONG);
  check(drawnGlb.drawn === glbTriangles, 'tandem view draws a Draco-compressed GLB whole',
        `${drawnGlb.drawn} of ${glbTriangles} triangles`);

  fs.writeFileSync(path.join(work, 'view-token'), 's3cret\n');
  const dirView = start('tandem', ['view', path.join(work, 'chunks'), '--view', '127.0.0.1:0',
                                   '--view-token-file', path.join(work, 'view-token'), '--linger', String(LONG)]);
  const dirUrl = await waitFor('tandem view DIR', () => urlIn(dirView), LONG);
  check(dirUrl.includes('?token=s3cret'), 'the printed address carries the token', dirUrl);
  check(!dirView.err.includes('warning'), 'no warning for a token read from a file', dirView.err);
  const refused = await fetch(dirUrl.replace(/\?token=.*/, 'state.json'));
  check(refused.status === 401, 'data without the token is refused', `HTTP ${refused.status}`);
  await page.goto(dirUrl);
  const dir = await waitFor('the chunks drawn', async () => {
    const v = await viewOf(page);
    return v && v.finished && v.chunks > 0 && v.chunks === v.state.chunks ? v : null;
  }, LONG);
  check(dir.drawn === metrics.triangles_final, 'tandem view DIR draws every chunk', `${dir.chunks} chunks, ${dir.drawn} triangles`);
  const dirNormals = await chunkNormals(page);
  check(dirNormals.shared > 0 && dirNormals.spread < 1e-6, 'tandem view DIR: one normal per vertex across chunks',
        JSON.stringify(dirNormals));
  await canvasShot(page, 'chunks.png');
  const errors = [...pageErrors, ...(await viewOf(page)).errors];
  check(errors.length === 0, 'no page errors', errors.join('; '));
});
