// Bundles Neuroglancer from node_modules (the npm package, pinned in package-lock.json) for
// the browser with esbuild: the page's module, the chunk worker and the async-computation
// worker, each a flat file, plus the package's WebAssembly decoders beside them. Neuroglancer
// finds the workers and decoders with `new URL(name, import.meta.url)`, so the test's server
// serves this folder's files by their base name at any path.
// usage: node tests/neuroglancer/bundle.mjs OUT_DIR   (skips the work when OUT_DIR is current)
import fs from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';

const out = path.resolve(process.argv[2] || 'build/neuroglancer-web');
const root = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '..', '..');
const esbuild = await import('esbuild');
const lib = path.join(root, 'node_modules', 'neuroglancer', 'lib');
const version = JSON.parse(fs.readFileSync(path.join(lib, '..', 'package.json'))).version;
const stamp = path.join(out, 'VERSION');
if (fs.existsSync(stamp) && fs.readFileSync(stamp, 'utf8') === version) process.exit(0);
fs.mkdirSync(out, { recursive: true });

// The icon set is a git dependency npm cannot fetch (package.json's override stands in an
// empty package): every icon is a blank SVG. fzstd (zstd chunks) is not in the package's
// dependencies and meshes never need it.
const stubs = {
  name: 'tandem-stubs',
  setup(build) {
    build.onResolve({ filter: /^ikonate\// }, (a) => ({ path: a.path, namespace: 'stub-svg' }));
    build.onLoad({ filter: /.*/, namespace: 'stub-svg' }, () => ({
      contents: '<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 24 24"></svg>',
      loader: 'text',
    }));
    build.onResolve({ filter: /^fzstd$/ }, (a) => ({ path: a.path, namespace: 'stub-js' }));
    build.onLoad({ filter: /.*/, namespace: 'stub-js' }, () => ({
      contents: 'export function decompress() { throw new Error("zstd is not bundled"); }',
      loader: 'js',
    }));
  },
};
await esbuild.build({
  entryPoints: ['main.bundle.js', 'chunk_worker.bundle.js', 'async_computation.bundle.js']
    .map((n) => path.join(lib, n)),
  outdir: out,
  bundle: true,
  format: 'esm',
  splitting: false,
  minify: true,
  target: 'chrome120',
  logLevel: 'error',
  plugins: [stubs],
  loader: { '.wasm': 'file', '.svg': 'text' },
  define: { 'process.env.NODE_ENV': '"production"' },
});
for (const dir of ['mesh/draco', 'sliceview/png', 'sliceview/jxl', 'sliceview/compresso']) {
  for (const f of fs.readdirSync(path.join(lib, dir)).filter((n) => n.endsWith('.wasm'))) {
    fs.copyFileSync(path.join(lib, dir, f), path.join(out, f));
  }
}
fs.writeFileSync(stamp, version);
console.log(`bundled neuroglancer ${version} into ${out}`);
