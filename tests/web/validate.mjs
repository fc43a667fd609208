// Runs the Khronos glTF Validator (npm gltf-validator) on one GLB and prints its report as
// JSON on stdout: {numErrors, numWarnings, numInfos, numHints, messages: [...]}.
// Usage: node validate.mjs scene.glb
import { readFileSync } from 'node:fs';
import validator from 'gltf-validator';

const path = process.argv[2];
if (!path) {
  console.error('usage: node validate.mjs <file.glb>');
  process.exit(2);
}
const bytes = new Uint8Array(readFileSync(path));
const report = await validator.validateBytes(bytes, {
  uri: path,
  maxIssues: 200,
  // a GLB of hirad's is self-contained: any external reference is reported, never read
  externalResourceFunction: (uri) => Promise.reject(new Error(`external resource ${uri}`)),
});
const out = {
  validatorVersion: report.validatorVersion,
  numErrors: report.issues.numErrors,
  numWarnings: report.issues.numWarnings,
  numInfos: report.issues.numInfos,
  numHints: report.issues.numHints,
  messages: report.issues.messages,
  info: report.info,
};
process.stdout.write(JSON.stringify(out));
