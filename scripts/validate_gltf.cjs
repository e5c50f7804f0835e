// Validate GLB files with the Khronos glTF validator (npm package gltf-validator).
// Usage: node scripts/validate_gltf.cjs <node_modules dir> file.glb [...]
// Prints one JSON line per file: {file, errors, warnings, messages[]}; exit 1 if any file has errors.
const path = require("path");
const fs = require("fs");
const validator = require(path.join(path.resolve(process.argv[2]), "gltf-validator"));

async function main() {
  let failed = false;
  for (const file of process.argv.slice(3)) {
    const data = new Uint8Array(fs.readFileSync(file));
    const report = await validator.validateBytes(data, { maxIssues: 50 });
    const issues = report.issues;
    const messages = issues.messages.filter((m) => m.severity <= 1).map((m) => `${m.code}: ${m.message} (${m.pointer || ""})`);
    console.log(JSON.stringify({ file, errors: issues.numErrors, warnings: issues.numWarnings, messages }));
    if (issues.numErrors > 0) failed = true;
  }
  process.exit(failed ? 1 : 0);
}
main().catch((e) => { console.error(String(e)); process.exit(2); });
