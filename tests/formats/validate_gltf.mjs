// Validates a .glb with the Khronos glTF validator (npm gltf-validator) and checks its
// counts. Usage: node validate_gltf.mjs FILE.glb VERTICES TRIANGLES
// Exit 0 when the validator reports no error and no warning and the file holds exactly
// VERTICES vertices and TRIANGLES triangles; 1 otherwise (the report is printed).
// A primitive compressed with KHR_draco_mesh_compression (which the validator does not
// decode) is decoded with Google's Draco decoder as three.js ships it (npm three,
// examples/jsm/libs/draco): its faces, points, and the POSITION and NORMAL attributes the
// extension names must match the accessors and the counts, and the normals be unit length.
import { readFileSync } from 'node:fs';
import { createRequire } from 'node:module';
import { dirname } from 'node:path';

const require = createRequire(import.meta.url);
const validator = require('gltf-validator');
const [file, vertices, triangles] = process.argv.slice(2);
const report = await validator.validateBytes(new Uint8Array(readFileSync(file)));
const info = report.info ?? {};
const problems = [];
if (report.issues.numErrors > 0 || report.issues.numWarnings > 0) {
  problems.push(`${report.issues.numErrors} errors, ${report.issues.numWarnings} warnings: ` +
                JSON.stringify(report.issues.messages.slice(0, 5)));
}
if (String(info.totalVertexCount) !== vertices) {
  problems.push(`totalVertexCount ${info.totalVertexCount}, expected ${vertices}`);
}
if (String(info.totalTriangleCount) !== triangles) {
  problems.push(`totalTriangleCount ${info.totalTriangleCount}, expected ${triangles}`);
}
const gltf = report.info && JSON.parse(glbJson(readFileSync(file)));
const draco = gltf?.meshes?.[0]?.primitives?.[0]?.extensions?.KHR_draco_mesh_compression;
if (draco) {
  const bytes = readFileSync(file);
  const view = gltf.bufferViews[draco.bufferView];
  const bin = glbBinary(bytes);
  const data = new Uint8Array(bin.buffer, bin.byteOffset + (view.byteOffset ?? 0), view.byteLength);
  // The package is an ES module package; the decoder is a CommonJS/UMD script: run it as one.
  const decoderPath = require.resolve('three/examples/jsm/libs/draco/draco_decoder.js');
  const cjs = { exports: {} };
  new Function('module', 'exports', 'require', '__filename', '__dirname',
               readFileSync(decoderPath, 'utf8'))(cjs, cjs.exports, require, decoderPath,
                                                  dirname(decoderPath));
  const Module = await cjs.exports();
  const decoder = new Module.Decoder();
  const mesh = new Module.Mesh();
  const status = decoder.DecodeArrayToMesh(data, data.byteLength, mesh);
  if (!status.ok()) problems.push(`Draco: ${status.error_msg()}`);
  const prim = gltf.meshes[0].primitives[0];
  if (String(mesh.num_faces()) !== triangles) problems.push(`Draco faces ${mesh.num_faces()}`);
  if (String(mesh.num_points()) !== vertices) problems.push(`Draco points ${mesh.num_points()}`);
  if (gltf.accessors[prim.indices].count !== 3 * mesh.num_faces()) problems.push('indices count');
  for (const semantic of ['POSITION', 'NORMAL']) {
    const att = decoder.GetAttributeByUniqueId(mesh, draco.attributes[semantic]);
    if (!att.ptr || att.num_components() !== 3) {
      problems.push(`Draco has no ${semantic} with id ${draco.attributes[semantic]}`);
      continue;
    }
    if (gltf.accessors[prim.attributes[semantic]].count !== mesh.num_points()) {
      problems.push(`${semantic} accessor count`);
    }
    const values = new Module.DracoFloat32Array();
    decoder.GetAttributeFloatForAllPoints(mesh, att, values);
    if (semantic === 'NORMAL') {
      for (let i = 0; i < mesh.num_points(); ++i) {
        const [x, y, z] = [values.GetValue(3 * i), values.GetValue(3 * i + 1), values.GetValue(3 * i + 2)];
        if (Math.abs(Math.hypot(x, y, z) - 1) > 1e-2) {
          problems.push(`normal ${i} has length ${Math.hypot(x, y, z)}`);
          break;
        }
      }
    }
    Module.destroy(values);
  }
  Module.destroy(mesh);
  Module.destroy(decoder);
}
if (problems.length > 0) {
  console.log(`${file}: ${problems.join('; ')}`);
  process.exit(1);
}
console.log(`${file}: valid glTF 2.0, ${vertices} vertices, ${triangles} triangles` +
            (draco ? ' (Draco-compressed, decoded by three.js\'s Draco decoder)' : ''));

// The JSON and BIN chunks of a GLB.
function glbJson(bytes) {
  const length = bytes.readUInt32LE(12);
  return bytes.subarray(20, 20 + length).toString('utf8');
}
function glbBinary(bytes) {
  const json = bytes.readUInt32LE(12);
  const at = 20 + json;
  return bytes.subarray(at + 8, at + 8 + bytes.readUInt32LE(at));
}
