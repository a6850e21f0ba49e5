// What the viewer's browser tests share: headless Debian Chromium driven by playwright-core
// (from the npm lockfile), the tandem binaries as children (killed at the end), bounded
// waits, and pass/fail bookkeeping. A test without Chromium or node_modules skips (exit 77)
// outside CI and fails in it (CI=true).
import { spawn } from 'node:child_process';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';

export function harness(buildDir) {
  const build = path.resolve(buildDir || 'build');
  const work = fs.mkdtempSync(path.join(os.tmpdir(), 'tandem-viewer-'));
  const shots = path.join(build, 'viewer-test');
  fs.mkdirSync(shots, { recursive: true });
  const chromiumPath = process.env.CHROMIUM || '/usr/bin/chromium';
  const children = [];
  let failures = 0, browser = null, chromium = null, PNG = null;
  const began = Date.now();
  const bin = (name) => path.join(build, 'bin', name);

  function skipOrFail(why) {
    if (process.env.CI === 'true') {
      console.error(`FAIL: ${why}`);
      process.exit(1);
    }
    console.log(`SKIP: ${why}`);
    process.exit(77);
  }
  function check(ok, what, detail = '') {
    const at = ((Date.now() - began) / 1000).toFixed(1);
    console.log(`${ok ? 'ok  ' : 'FAIL'} [${at} s] ${what}${detail ? `: ${detail}` : ''}`);
    if (!ok) failures++;
    return ok;
  }
  function start(name, args, env = {}) {
    const child = spawn(bin(name), args, { cwd: work, stdio: ['ignore', 'pipe', 'pipe'],
                                           env: { ...process.env, ...env } });
    child.out = '';
    child.err = '';
    child.stdout.on('data', (d) => { child.out += d; });
    child.stderr.on('data', (d) => { child.err += d; });
    child.exited = new Promise((resolve) => child.on('exit', (code) => { child.code = code; resolve(code); }));
    children.push(child);
    return child;
  }
  const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
  async function waitFor(what, fn, seconds) {
    const until = Date.now() + seconds * 1000;
    while (Date.now() < until) {
      const v = await fn();
      if (v) return v;
      await sleep(100);
    }
    throw new Error(`timed out after ${seconds} s waiting for ${what}`);
  }
  // The viewer address a tandem or tandem-client child printed.
  const urlIn = (child) => (child.err.match(/(http:\/\/127\.0\.0\.1:\d+\/\S*)/) || [])[1];
  // A tandem-server on a free loopback port; resolves to its address.
  async function startServer(args = []) {
    const server = start('tandem-server', ['--listen', '127.0.0.1:0', ...args]);
    return (await waitFor('the server address',
                          () => (server.out + server.err).match(/listening on (127\.0\.0\.1:\d+)/), 120))[1];
  }

  // Chromium, playwright-core and pngjs, or skip/fail if they are missing (before any child
  // is started).
  async function prerequisites() {
    if (!fs.existsSync(chromiumPath)) skipOrFail(`${chromiumPath} is missing (apt-get install chromium)`);
    try {
      ({ chromium } = await import('playwright-core'));
      ({ PNG } = await import('pngjs'));
    } catch (e) {
      skipOrFail(`node_modules is missing (bash deploy/install-web.sh): ${e.message}`);
    }
  }
  // Headless Chromium drawing with SwiftShader (no GPU needed).
  async function launch() {
    browser = await chromium.launch({
      executablePath: chromiumPath,
      args: ['--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--no-sandbox'],
    });
    return browser;
  }

  // The 3D view alone (the canvas, not the panel), as a PNG file in the shots folder.
  async function canvasShot(page, name) {
    const file = path.join(shots, name);
    await page.locator('#view canvas').screenshot({ path: file, timeout: 120000 });
    return file;
  }
  // The whole page (panel and view), for the docs (viewer/screenshots).
  async function pageShot(page, name) {
    await page.screenshot({ path: path.join(shots, name), timeout: 120000 });
  }
  // Pixels of a canvas screenshot that differ from the page's background, as
  // {share, mean: [r, g, b] of those pixels, chroma: mean of r,g,b / (r+g+b)}.
  const BACKGROUND = [0x16, 0x18, 0x1d];
  function pixels(file) {
    const png = PNG.sync.read(fs.readFileSync(file));
    let lit = 0;
    const sum = [0, 0, 0], chroma = [0, 0, 0];
    for (let i = 0; i < png.width * png.height * 4; i += 4) {
      const rgb = [png.data[i], png.data[i + 1], png.data[i + 2]];
      const d = rgb.reduce((n, c, k) => n + Math.abs(c - BACKGROUND[k]), 0);
      if (d <= 30) continue;
      lit++;
      const total = rgb[0] + rgb[1] + rgb[2] || 1;
      for (let k = 0; k < 3; k++) { sum[k] += rgb[k]; chroma[k] += rgb[k] / total; }
    }
    const n = Math.max(lit, 1);
    return { share: lit / (png.width * png.height), mean: sum.map((v) => v / n), chroma: chroma.map((v) => v / n) };
  }
  const coverage = (file) => pixels(file).share;
  // A colour '#rrggbb' as chromaticity r,g,b / (r+g+b), and the distance of two of them.
  const chromaOf = (hex) => {
    const rgb = [1, 3, 5].map((k) => parseInt(hex.slice(k, k + 2), 16));
    const total = rgb[0] + rgb[1] + rgb[2];
    return rgb.map((c) => c / total);
  };
  const chromaDistance = (a, b) => Math.hypot(a[0] - b[0], a[1] - b[1], a[2] - b[2]);

  // Copies slices [from, to) of a folder of numbered TIFFs into the folder a client follows
  // (each under a temporary name first, then renamed into place: a reader never sees half a
  // file). Returns the count copied so far.
  function copySlices(staged, target, from, to) {
    const names = fs.readdirSync(staged).filter((n) => n.endsWith('.tif')).sort();
    for (let i = from; i < Math.min(to, names.length); i++) {
      fs.copyFileSync(path.join(staged, names[i]), path.join(target, `${names[i]}.part`));
      fs.renameSync(path.join(target, `${names[i]}.part`), path.join(target, names[i]));
    }
    return Math.min(to, names.length);
  }

  // Runs the test's body; a throw is one failed check. Then closes the browser, kills the
  // children and exits 0 (passed) or 1.
  async function run(body) {
    await prerequisites();
    try {
      await body();
    } catch (e) {
      check(false, 'the test ran to its end', e.stack || String(e));
    } finally {
      if (browser) await browser.close().catch(() => {});
      for (const c of children) {
        if (c.exitCode === null) c.kill('SIGKILL');
      }
    }
    console.log(failures === 0 ? 'PASS' : `${failures} check(s) failed`);
    process.exit(failures === 0 ? 0 : 1);
  }

  return { build, work, shots, bin, check, start, sleep, waitFor, urlIn, startServer, launch,
           canvasShot, pageShot, pixels, coverage, chromaOf, chromaDistance, copySlices, run };
}
