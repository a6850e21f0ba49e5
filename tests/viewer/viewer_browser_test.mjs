// The live viewer in a real browser: headless Debian Chromium (driven by playwright-core)
// loads the page of `tandem-client stream --view` while a paced, sealed stream runs
// against the real tandem-server on 127.0.0.1, and checks that the mesh is drawn (a
// screenshot whose non-background pixels cover a share of the view), that it grows, that
// the final counts shown equal the final metrics, that a reload catches up, and that
// `tandem view` shows a finished mesh file and a folder of chunks (behind a token, the
// page's own files included, read from a file or the environment), and refuses a busy port
// by name. Every wait is bounded; children are killed at the end.
//   node tests/viewer/viewer_browser_test.mjs BUILD_DIR
// Exit 0: passed; 1: failed; 77: skipped (no Chromium or node_modules, outside CI).
import { spawnSync } from 'node:child_process';
import fs from 'node:fs';
import path from 'node:path';
import { harness } from './browser_harness.mjs';

const { work, shots, bin, check, start, waitFor, urlIn, startServer, launch, coverage, run } =
  harness(process.argv[2]);

await run(async () => {
  const volume = path.join(work, 'gyroid.json');
  const gen = spawnSync(bin('tandem'), ['generate', 'gyroid', '--size', '96', '--out', volume]);
  if (gen.status !== 0) throw new Error(`tandem generate: ${gen.stderr}`);
  // Band previews up to 4x the chunks' bytes (default: a quarter, which allows only a few
  // over a short scan), so that the live view has a fresh band to show.
  const address = await startServer(['--max-band-bytes-share', '4']);

  // 96 slices at 5 per second: about 19 s of scan, so that a browser started on a loaded
  // machine (Chromium's launch and first frame took over 8 s at a load of 5 on 2 cores)
  // still sees the scan running.
  const client = start('tandem-client', [
    'stream', '--server', address, '--input', volume, '--iso', '0', '--error', '0.05',
    '--seal', '--rate', '5', '--preview-every', '4', '--out', path.join(work, 'gyroid.ply'),
    '--chunks', path.join(work, 'chunks'), '--metrics', path.join(work, 'gyroid.json.metrics'),
    '--view', '127.0.0.1:0', '--view-linger', '60']);
  const url = await waitFor('the viewer address', () => urlIn(client), 20);
  const browser = await launch();
  const page = await browser.newPage({ viewport: { width: 960, height: 640 } });
  const pageErrors = [];
  page.on('pageerror', (e) => pageErrors.push(e.message));
  await page.goto(url);
  const view = () => page.evaluate(() => {
    const v = window.tandemView;
    return v && { drawn: v.trianglesDrawn, chunks: v.chunksDrawn, band: v.bandTriangles,
                  finished: v.finished, errors: v.errors,
                  shown: document.getElementById('drawn').textContent };
  });

  // Live: drawn before the end, and growing.
  const early = await waitFor('a part of the mesh drawn while the scan runs', async () => {
    const v = await view();
    return v && (v.finished || (v.chunks >= 1 && v.drawn >= 2000 && v.band > 0)) ? v : null;
  }, 40);
  check(!early.finished, 'chunks and the band are drawn while the scan still runs', JSON.stringify(early));
  await page.screenshot({ path: path.join(shots, 'live.png') });
  const liveCoverage = coverage(path.join(shots, 'live.png'));
  check(liveCoverage > 0.01, 'the live screenshot shows the mesh', `${(100 * liveCoverage).toFixed(1)} % of the view`);

  const done = await waitFor('the end of the stream', async () => {
    const v = await view();
    return v && v.finished ? v : null;
  }, 60);
  // The sealed part only grows. (All drawn, chunks plus band, need not: the band holds the
  // front's triangles not simplified yet, so near the end it can exceed the final count.)
  const sealedEarly = early.drawn - early.band, sealedDone = done.drawn - done.band;
  check(sealedDone > sealedEarly, 'the mesh grows',
        `${sealedEarly} then ${sealedDone} sealed triangles (${early.drawn} then ${done.drawn} drawn)`);
  await waitFor('the client to write its metrics', () => fs.existsSync(path.join(work, 'gyroid.json.metrics')), 20);
  const metrics = JSON.parse(fs.readFileSync(path.join(work, 'gyroid.json.metrics'), 'utf8'));
  check(done.drawn === metrics.triangles_final, 'triangles drawn = the final metrics', `${done.drawn} vs ${metrics.triangles_final}`);
  check(done.shown === metrics.triangles_final.toLocaleString('en-US'), 'the panel shows that count', done.shown);
  const shownFinal = await page.evaluate(() => document.getElementById('metric-triangles_final')?.textContent);
  check(shownFinal === String(metrics.triangles_final), 'the final metrics table shows triangles_final', shownFinal);
  await page.screenshot({ path: path.join(shots, 'final.png') });
  const finalCoverage = coverage(path.join(shots, 'final.png'));
  check(finalCoverage > 0.05, 'the final screenshot shows the mesh', `${(100 * finalCoverage).toFixed(1)} % of the view`);

  // The clipping plane cuts the mesh (half of it gone), reset view brings back the framing.
  await page.check('#clip');
  await page.waitForTimeout(300);
  await page.screenshot({ path: path.join(shots, 'clipped.png') });
  const clipped = coverage(path.join(shots, 'clipped.png'));
  check(clipped > 0.01 && clipped < 0.85 * finalCoverage, 'the clipping plane cuts the mesh',
        `${(100 * clipped).toFixed(1)} % of the view against ${(100 * finalCoverage).toFixed(1)} %`);
  await page.uncheck('#clip');
  await page.mouse.move(700, 300);
  await page.mouse.wheel(0, 2000);  // zoom out
  await page.waitForTimeout(300);
  await page.click('#reset');
  await page.waitForTimeout(300);
  await page.screenshot({ path: path.join(shots, 'reset.png') });
  const reset = coverage(path.join(shots, 'reset.png'));
  check(Math.abs(reset - finalCoverage) < 0.2 * finalCoverage, 'reset view frames the mesh again',
        `${(100 * reset).toFixed(1)} % of the view`);

  // A late viewer of the finished session (tandem-client view: the watch RPC) draws it all.
  const session = (client.err.match(/session ([0-9a-f]{32})/) || [])[1];
  // Sessions are private: the watch key the streaming client printed lets the viewer read it.
  const watchKey = (client.err.match(/TANDEM_WATCH_KEY=([0-9a-f]{32})/) || [])[1];
  // Its token from the environment: the page's own files need it too, and the browser
  // gets them through the cookie the printed address gives it.
  const watcher = start('tandem-client', ['view', '--server', address, '--session', session,
                                          '--view', '127.0.0.1:0', '--view-linger', '60'],
                        { TANDEM_VIEW_TOKEN: 'w4tch', TANDEM_WATCH_KEY: watchKey });
  const watchUrl = await waitFor('tandem-client view', () => urlIn(watcher), 20);
  check(watchUrl.includes('?token=w4tch'), 'the token from $TANDEM_VIEW_TOKEN', watchUrl);
  const script = await fetch(watchUrl.replace(/\?token=.*/, 'viewer.js'));
  check(script.status === 401, "the page's files need the token too", `HTTP ${script.status}`);
  const watchPage = await browser.newPage({ viewport: { width: 960, height: 640 } });
  await watchPage.goto(watchUrl);
  const watched = await waitFor('the watched session drawn', () => watchPage.evaluate(() => {
    const v = window.tandemView;
    return v && v.finished && v.chunksDrawn === v.state.chunks ? v.trianglesDrawn : null;
  }), 30);
  check(watched === metrics.triangles_final, 'tandem-client view draws the watched session', `${watched} triangles`);
  await watchPage.close();

  // A reload (or a late browser) catches up from the immutable chunks.
  await page.reload();
  const again = await waitFor('the reloaded page to catch up', async () => {
    const v = await view();
    return v && v.finished && v.drawn === metrics.triangles_final ? v : null;
  }, 30);
  check(again.chunks === done.chunks, 'the reloaded page draws every chunk again', `${again.chunks} chunks`);
  check(pageErrors.length === 0 && again.errors.length === 0, 'no page errors', [...pageErrors, ...again.errors].join('; '));

  // tandem view: a finished file, and a folder of chunks behind a token.
  const plyView = start('tandem', ['view', path.join(work, 'gyroid.ply'), '--view', '127.0.0.1:0', '--linger', '60']);
  const plyUrl = await waitFor('tandem view MESH', () => urlIn(plyView), 20);
  await page.goto(plyUrl);
  const ply = await waitFor('the PLY file drawn', async () => {
    const v = await view();
    return v && v.drawn > 0 ? v : null;
  }, 30);
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
  const glbView = start('tandem', ['view', glb, '--view', '127.0.0.1:0', '--linger', '60']);
  await page.goto(await waitFor('tandem view GLB', () => urlIn(glbView), 20));
  const drawnGlb = await waitFor('the Draco GLB drawn', async () => {
    const v = await view();
    return v && v.drawn > 0 ? v : null;
  }, 30);
  check(drawnGlb.drawn === glbTriangles, 'tandem view draws a Draco-compressed GLB whole',
        `${drawnGlb.drawn} of ${glbTriangles} triangles`);

  fs.writeFileSync(path.join(work, 'view-token'), 's3cret\n');
  const dirView = start('tandem', ['view', path.join(work, 'chunks'), '--view', '127.0.0.1:0',
                                   '--view-token-file', path.join(work, 'view-token'), '--linger', '60']);
  const dirUrl = await waitFor('tandem view DIR', () => urlIn(dirView), 20);
  check(dirUrl.includes('?token=s3cret'), 'the printed address carries the token', dirUrl);
  check(!dirView.err.includes('warning'), 'no warning for a token read from a file', dirView.err);
  const refused = await fetch(dirUrl.replace(/\?token=.*/, 'state.json'));
  check(refused.status === 401, 'data without the token is refused', `HTTP ${refused.status}`);
  await page.goto(dirUrl);
  const dir = await waitFor('the chunks drawn', async () => {
    const v = await view();
    return v && v.finished && v.chunks > 0 && v.chunks === (await page.evaluate(() => window.tandemView.state.chunks)) ? v : null;
  }, 30);
  check(dir.drawn === metrics.triangles_final, 'tandem view DIR draws every chunk', `${dir.chunks} chunks, ${dir.drawn} triangles`);
  await page.screenshot({ path: path.join(shots, 'chunks.png') });
});
