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
    console.log(`${ok ? 'ok  ' : 'FAIL'} ${what}${detail ? `: ${detail}` : ''}`);
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
                          () => (server.out + server.err).match(/listening on (127\.0\.0\.1:\d+)/), 20))[1];
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

  // Share of a screenshot's view right of the panel whose pixels differ from the page's
  // background.
  function coverage(file) {
    const png = PNG.sync.read(fs.readFileSync(file));
    const bg = [0x16, 0x18, 0x1d];
    let lit = 0, all = 0;
    for (let y = 0; y < png.height; y++) {
      for (let x = 330; x < png.width; x++) {
        const i = (y * png.width + x) * 4;
        const d = Math.abs(png.data[i] - bg[0]) + Math.abs(png.data[i + 1] - bg[1]) + Math.abs(png.data[i + 2] - bg[2]);
        if (d > 30) lit++;
        all++;
      }
    }
    return lit / all;
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

  return { build, work, shots, bin, check, start, sleep, waitFor, urlIn, startServer, launch, coverage, run };
}
