// Validates a .glb with the Khronos glTF validator (npm gltf-validator) and checks its
// counts. Usage: node validate_gltf.mjs FILE.glb VERTICES TRIANGLES
// Exit 0 when the validator reports no error and no warning and the file holds exactly
// VERTICES vertices and TRIANGLES triangles; 1 otherwise (the report is printed).
import { readFileSync } from 'node:fs';
import { createRequire } from 'node:module';

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
if (problems.length > 0) {
  console.log(`${file}: ${problems.join('; ')}`);
  process.exit(1);
}
console.log(`${file}: valid glTF 2.0, ${vertices} vertices, ${triangles} triangles`);
