// The live viewer of a label session in a real browser: headless Debian Chromium loads the
// page of `tandem-client stream --labels --label-names TABLE --view` against the real
// tandem-server on 127.0.0.1, on a label map the test writes (three labels: two touching
// boxes and a ball, uint16, raw + JSON sidecar). Mid-scan the page draws each label as a
// surface of its own in the colour the 3D Slicer table gives it (the canvas holds at least
// two of those colours, told apart by their chromaticity); at the end every label's final
// mesh is drawn in its colour and the final table has a row per label.
// With `sealed` (--seal) the labels come as sealed chunks, each drawn on its label's surface,
// and at the end the chunks are each label's whole mesh. With `watched` the same sealed session
// is shown by another client, `tandem-client watch --label-names TABLE --view`, which also
// writes the streaming client's files.
//   node tests/viewer/viewer_labels_test.mjs BUILD_DIR [sealed|watched]
// Exit 0: passed; 1: failed; 77: skipped (no Chromium or node_modules, outside CI).
import fs from 'node:fs';
import path from 'node:path';
import { harness } from './browser_harness.mjs';

const { work, check, start, waitFor, urlIn, startServer, launch, canvasShot, pageShot, chromaOf,
        chromaDistance, run } = harness(process.argv[2]);

const WATCHED = process.argv[3] === 'watched';
const SEALED = process.argv[3] === 'sealed' || WATCHED;
const drawn = (s) => s.bandTriangles + s.sealedTriangles;
const LONG = 240;  // bound of every wait, in seconds (the waits take a few)
const N = 48;      // grid vertices per axis
// The labels, their names and colours (a 3D Slicer colour table: id name r g b a).
const LABELS = [[1, 'Red', [220, 40, 40]], [2, 'Green', [40, 200, 60]], [5, 'Blue', [40, 80, 230]]];
const hex = (rgb) => `#${rgb.map((c) => c.toString(16).padStart(2, '0')).join('')}`;

// Two touching boxes (labels 1 and 2) and a ball above them (label 5), in background 0.
function writeVolume(file) {
  const data = Buffer.alloc(2 * N * N * N);
  for (let z = 0; z < N; z++) {
    for (let y = 0; y < N; y++) {
      for (let x = 0; x < N; x++) {
        let l = 0;
        if (z >= 6 && z < 24 && y >= 8 && y < 40 && x >= 6 && x < 42) l = x < 24 ? 1 : 2;
        if (Math.hypot(x - 24, y - 24, z - 34) < 9) l = 5;
        data.writeUInt16LE(l, 2 * ((z * N + y) * N + x));
      }
    }
  }
  fs.writeFileSync(`${file}.raw`, data);
  fs.writeFileSync(`${file}.json`, JSON.stringify({
    dims: [N, N, N], dtype: 'uint16', spacing: [1, 1, 1], origin: [0, 0, 0],
    byte_order: 'little', raw_file: `${path.basename(file)}.raw`, raw_bytes: data.length,
  }));
  return `${file}.json`;
}

// Shares of a canvas screenshot's pixels whose chromaticity is nearest to each colour's, and
// near it (lit pixels only; shading keeps a colour's chromaticity, the lights tint it a little).
async function colourShares(file, colours) {
  const { PNG } = await import('pngjs');
  const png = PNG.sync.read(fs.readFileSync(file));
  const counts = colours.map(() => 0);
  const pixels = png.width * png.height;
  const targets = colours.map(chromaOf);
  for (let i = 0; i < 4 * pixels; i += 4) {
    const rgb = [png.data[i], png.data[i + 1], png.data[i + 2]];
    const total = rgb[0] + rgb[1] + rgb[2];
    if (total < 60) continue;  // the background and deep shadow
    const chroma = rgb.map((c) => c / total);
    const d = targets.map((t) => chromaDistance(chroma, t));
    const k = d.indexOf(Math.min(...d));
    if (d[k] < 0.15) counts[k]++;
  }
  return counts.map((c) => c / pixels);
}

const viewOf = (page) => page.evaluate(() => {
  const v = window.tandemView;
  return v && v.state && { finished: v.finished, errors: v.errors, rendered: v.rendered,
                           surfaces: v.surfaces(), meshed: v.state.slices_meshed,
                           metricRows: [...document.querySelectorAll('#metrics tr.surface-head')].map((r) => r.textContent.trim()) };
});

await run(async () => {
  const volume = writeVolume(path.join(work, 'labels'));
  const table = path.join(work, 'colors.ctbl');
  fs.writeFileSync(table, `# id name r g b a\n0 Background 0 0 0 0\n${
    LABELS.map(([id, name, rgb]) => `${id} ${name} ${rgb.join(' ')} 255`).join('\n')}\n`);
  const address = await startServer(['--idle-timeout-seconds', '900']);
  const browser = await launch();
  // Paced (4 slices a second): the page is looked at while the scan is still arriving.
  const view = ['--view', '127.0.0.1:0', '--view-linger', String(LONG)];
  const client = start('tandem-client', [
    'stream', '--server', address, '--input', volume, '--labels', '--label-names', table,
    '--error', '0.5', '--rate', '4', '--out', path.join(work, 'out') + '/',
    ...(WATCHED ? ['--preview-every', '2'] : view), ...(SEALED ? ['--seal'] : [])]);
  let viewer = client;
  if (WATCHED) {  // another client shows the session, by the id and key the streamer printed
    const printed = (name) => (client.err.match(new RegExp(`${name}=([0-9a-f]{32})`)) || [])[1];
    const key = await waitFor('the watch key', () => printed('TANDEM_WATCH_KEY'), LONG);  // printed last
    viewer = start('tandem-client', [
      'watch', '--server', address, '--session', printed('TANDEM_RESUME'), '--label-names', table,
      '--out', path.join(work, 'watched') + '/', ...view], { TANDEM_WATCH_KEY: key });
  }
  const url = await waitFor('the viewer address', () => urlIn(viewer), LONG);
  const page = await browser.newPage({ viewport: { width: 960, height: 640 } });
  const pageErrors = [];
  page.on('pageerror', (e) => pageErrors.push(e.message));
  await page.goto(url);

  const colours = LABELS.map(([, , rgb]) => hex(rgb));
  const mid = await waitFor('two labels drawn mid-scan', async () => {
    const v = await viewOf(page);
    return v && !v.finished && v.rendered &&
           v.surfaces.filter((s) => drawn(s) > 0).length >= 2 ? v : null;
  }, LONG);
  check(mid.meshed < N, 'labels: the scan is still running', `${mid.meshed} of ${N} slices meshed`);
  const named = mid.surfaces.filter((s) => drawn(s) > 0);
  check(named.every((s) => LABELS.some(([id, name, rgb]) => s.label === `${name} (${id})` && s.bandColor === hex(rgb))),
        'labels: each label drawn mid-scan is a surface named and coloured by the table',
        JSON.stringify(named.map((s) => [s.label, s.bandColor, drawn(s)])));
  const live = await colourShares(await canvasShot(page, 'labels-live.png'), colours);
  check(live.filter((share) => share > 0.003).length >= 2,
        'labels: the live canvas shows at least two of the labels\' colours', JSON.stringify(live));

  const end = await waitFor('the final meshes drawn', async () => {
    const v = await viewOf(page);
    return v && v.finished && v.rendered && v.metricRows.length > 0 ? v : null;
  }, LONG);
  check(end.surfaces.length === 3 && end.surfaces.every((s) => drawn(s) > 0),
        'labels: every label\'s final mesh is drawn', JSON.stringify(end.surfaces.map((s) => [s.label, drawn(s)])));
  if (SEALED) {
    check(end.surfaces.every((s) => s.sealedTriangles > 0 && s.bandTriangles === 0),
          'labels, sealed: each label\'s chunks are its whole mesh, drawn on its own surface',
          JSON.stringify(end.surfaces.map((s) => [s.label, s.sealedTriangles, s.bandTriangles])));
  }
  check(end.metricRows.length === 3 && LABELS.every(([id, name]) => end.metricRows.some((r) => r.includes(`${name} (${id})`))),
        'labels: the final table has a row per label', JSON.stringify(end.metricRows));
  const final = await colourShares(await canvasShot(page, 'labels-final.png'), colours);
  check(final.every((share) => share > 0.003), 'labels: the final canvas shows all three colours',
        JSON.stringify(final));
  await pageShot(page, 'page-labels-final.png');
  if (WATCHED) {
    check(await client.exited === 0, 'labels: the streaming client ends well', client.err.slice(-2000));
  }
  const want = ['Blue.ply', 'Green.ply', 'Red.ply', 'labels.glb'];
  for (const dir of WATCHED ? ['out', 'watched'] : ['out']) {
    await waitFor(`${dir}/labels.glb`, () => fs.existsSync(path.join(work, dir, 'labels.glb')), LONG);
    const files = fs.readdirSync(path.join(work, dir)).sort();
    check(JSON.stringify(files) === JSON.stringify(want),
          `labels: ${dir}/ holds a file per label, named by the table, and labels.glb`, JSON.stringify(files));
    check(want.every((f) => fs.readFileSync(path.join(work, dir, f)).equals(fs.readFileSync(path.join(work, 'out', f)))),
          `labels: ${dir}/ holds the streaming client's files`, dir);
  }
  viewer.kill('SIGINT');  // the end of --view-linger
  const code = await viewer.exited;
  check(code === 0, 'labels: the client ends well', viewer.err.slice(-2000));
  check(pageErrors.length === 0 && end.errors.length === 0, 'labels: no error on the page',
        JSON.stringify([...pageErrors, ...end.errors]));
});
