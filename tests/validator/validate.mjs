// Validates .glb/.gltf files with the Khronos glTF-Validator (npm package
// `gltf-validator`) and prints each report's issue counts and messages.
//
//   node tests/validator/validate.mjs [--prefix DIR] FILE...
//
// --prefix is the folder gltf-validator was installed into with
// `npm install --prefix DIR gltf-validator` (default: Node's own module
// resolution from this script's folder). Exit status: 0 when no file has
// an error, 1 when one has (warnings, infos and hints are printed but do
// not fail), 2 on bad arguments or a file that cannot be read.

import { readFile } from "node:fs/promises";
import { createRequire } from "node:module";
import path from "node:path";

const USAGE = "usage: node validate.mjs [--prefix DIR] FILE...";
const args = process.argv.slice(2);
let prefix = null;
const files = [];
for (let i = 0; i < args.length; i++) {
    if (args[i] === "--prefix") {
        prefix = args[++i];
        if (prefix === undefined) {
            console.error(`--prefix needs a folder\n${USAGE}`);
            process.exit(2);
        }
    } else if (args[i] === "-h" || args[i] === "--help") {
        console.log(USAGE);
        process.exit(0);
    } else {
        files.push(args[i]);
    }
}
if (files.length === 0) {
    console.error(USAGE);
    process.exit(2);
}

// Load the validator from the npm prefix (createRequire resolves
// `node_modules/` under the folder it is given, as npm lays it out).
const from = prefix
    ? path.resolve(prefix, "package.json")
    : import.meta.url;
let validator;
try {
    validator = createRequire(from)("gltf-validator");
} catch (e) {
    console.error(`cannot load gltf-validator${prefix ? ` from ${prefix}` : ""}: ${e.message}`);
    process.exit(2);
}
console.log(`glTF-Validator ${validator.version()}`);

const SEVERITY = ["error", "warning", "info", "hint"];
let failed = false;
for (const file of files) {
    let bytes;
    try {
        bytes = new Uint8Array(await readFile(file));
    } catch (e) {
        console.error(`${file}: ${e.message}`);
        process.exit(2);
    }
    // Resources outside the file (a .gltf's .bin, textures) are read from
    // its folder.
    const externalResourceFunction = async (uri) =>
        new Uint8Array(await readFile(path.resolve(path.dirname(file), decodeURIComponent(uri))));
    let report;
    try {
        report = await validator.validateBytes(bytes, {
            uri: path.basename(file),
            maxIssues: 0,
            writeTimestamp: false,
            externalResourceFunction,
        });
    } catch (e) {
        console.error(`${file}: the validator could not read it: ${e}`);
        failed = true;
        continue;
    }
    const s = report.issues;
    console.log(
        `${file}: ${s.numErrors} errors, ${s.numWarnings} warnings, ` +
            `${s.numInfos} infos, ${s.numHints} hints`
    );
    for (const m of s.messages) {
        console.log(`  ${SEVERITY[m.severity] ?? m.severity} ${m.code} at ${m.pointer ?? "(file)"}: ${m.message}`);
    }
    if (s.numErrors > 0) {
        failed = true;
    }
}
process.exit(failed ? 1 : 0);
