// Validate a .glb with the Khronos glTF-Validator (npm gltf-validator, pinned in package.json).
// Usage: node scripts/validate-gltf.mjs FILE.glb  → prints the issue counts and messages as JSON;
// exit status 1 when the file has errors.
import fs from 'fs';
import validator from 'gltf-validator';

const data = new Uint8Array(fs.readFileSync(process.argv[2]));
const report = await validator.validateBytes(data, { maxIssues: 200 });
const { numErrors, numWarnings, numInfos, messages } = report.issues;
console.log(JSON.stringify({ numErrors, numWarnings, numInfos, messages: messages.slice(0, 50) }, null, 1));
process.exit(numErrors > 0 ? 1 : 0);
