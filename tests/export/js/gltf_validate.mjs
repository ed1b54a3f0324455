// Khronos glTF-Validator (npm gltf-validator) on exported .gltf files, external resources read from disk.
// Usage: node gltf_validate.mjs FILE.gltf ... ; prints {file: {numErrors, numWarnings, numInfos, messages}}.
import { readFileSync } from 'node:fs';
import { dirname, join } from 'node:path';
import { createRequire } from 'node:module';

const validator = createRequire(import.meta.url)('gltf-validator');
const out = {};
for (const file of process.argv.slice(2)) {
  const report = await validator.validateBytes(new Uint8Array(readFileSync(file)), {
    uri: file, maxIssues: 100,
    externalResourceFunction: (uri) => Promise.resolve(new Uint8Array(readFileSync(join(dirname(file), decodeURIComponent(uri))))),
  });
  out[file] = { numErrors: report.issues.numErrors, numWarnings: report.issues.numWarnings,
                numInfos: report.issues.numInfos,
                messages: report.issues.messages.map((m) => `${m.severity} ${m.code} ${m.pointer ?? ''} ${m.message}`) };
}
process.stdout.write(JSON.stringify(out));
