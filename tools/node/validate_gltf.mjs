// Validates a .glb / .gltf with the Khronos glTF-Validator (npm gltf-validator)
// and prints its report's counts and messages as JSON. Exit 0 when the file
// has no errors and no warnings, 1 otherwise, 2 when it cannot be read.
// Usage: node tools/node/validate_gltf.mjs FILE
import fs from 'fs';
import validator from 'gltf-validator';

const file = process.argv[2];
if (!file) {
  console.error('usage: node validate_gltf.mjs FILE');
  process.exit(2);
}
let bytes;
try {
  bytes = new Uint8Array(fs.readFileSync(file));
} catch (e) {
  console.error(`cannot read ${file}: ${e.message}`);
  process.exit(2);
}
const report = await validator.validateBytes(bytes, { maxIssues: 100 });
const issues = report.issues;
console.log(JSON.stringify({
  validator: report.validatorVersion,
  errors: issues.numErrors,
  warnings: issues.numWarnings,
  infos: issues.numInfos,
  hints: issues.numHints,
  triangles: report.info ? report.info.totalTriangleCount : 0,
  messages: issues.messages,
}, null, 1));
process.exit(issues.numErrors === 0 && issues.numWarnings === 0 ? 0 : 1);
