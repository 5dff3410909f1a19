// Validates a .glb with the Khronos glTF-Validator (npm package gltf-validator) and prints its
// report summary as JSON; exit 1 when it reports an error.
//   npm install gltf-validator && node scripts/gltf-validate.js OUT.glb
const fs = require("fs");
const validator = require("gltf-validator");
const path = process.argv[2];
const data = new Uint8Array(fs.readFileSync(path));
validator
  .validateBytes(data, { maxIssues: 100 })
  .then((report) => {
    const i = report.issues;
    console.log(JSON.stringify({
      file: path, bytes: data.length, errors: i.numErrors, warnings: i.numWarnings, infos: i.numInfos, hints: i.numHints,
      messages: i.messages.map((m) => `${m.severity} ${m.code} ${m.pointer || ""}: ${m.message}`),
      info: report.info,
    }, null, 1));
    process.exit(i.numErrors > 0 ? 1 : 0);
  })
  .catch((e) => { console.error("validation failed:", e); process.exit(2); });
