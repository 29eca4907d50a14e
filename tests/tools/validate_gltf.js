// Validates every .glb under a directory with the Khronos glTF validator and
// prints one JSON summary line: {"files", "errors", "warnings", "messages",
// "infos"}; "messages" holds the first errors and warnings, "infos" counts
// the infos by code and pointer ("UNUSED_OBJECT /buffers/0"), or by code
// and extension name ("UNSUPPORTED_EXTENSION KHR_meshopt_compression").
// Usage: node tests/tools/validate_gltf.js DIR
'use strict';
const fs = require('fs');
const path = require('path');
const validator = require('gltf-validator');

function walk(dir, out) {
  for (const e of fs.readdirSync(dir, { withFileTypes: true })) {
    const p = path.join(dir, e.name);
    if (e.isDirectory()) walk(p, out);
    else if (e.name.endsWith('.glb')) out.push(p);
  }
  return out;
}

(async () => {
  const files = walk(process.argv[2], []).sort();
  let errors = 0, warnings = 0;
  const messages = [];
  const infos = {};
  for (const f of files) {
    const report = await validator.validateBytes(new Uint8Array(fs.readFileSync(f)), { maxIssues: 50 });
    errors += report.issues.numErrors;
    warnings += report.issues.numWarnings;
    for (const m of report.issues.messages) {
      if (m.severity <= 1 && messages.length < 20) messages.push(`${f}: ${m.code} ${m.pointer || ''} ${m.message}`);
      if (m.severity === 2) {
        const ext = m.code === 'UNSUPPORTED_EXTENSION' ? (m.message.match(/'([^']+)'/) || [])[1] : undefined;
        const key = `${m.code} ${ext || m.pointer || ''}`.trim();
        infos[key] = (infos[key] || 0) + 1;
      }
    }
  }
  console.log(JSON.stringify({ files: files.length, errors, warnings, messages, infos }));
})().catch((e) => { console.error(e); process.exit(2); });
