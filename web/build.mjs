#!/usr/bin/env node
// Copy the browser files `fracture view` needs into the package's static/vendor/ folder:
// three.js's module build, the addons the page imports (and the addon files they import in
// turn), three's licence, and the runtime reader engines/web/fracture_runtime.js.
//
//   node web/build.mjs NODE_MODULES_DIR OUT_DIR
//
// The page loads these through an import map (three -> vendor/three.module.js,
// three/addons/ -> vendor/addons/), so nothing is fetched from the internet at run time.
// Also the aligned-fracture reader engines/web/fracture_aligned.js (the page's "cut at the click" mode).
// Nothing here is committed: OUT_DIR is gitignored and rebuilt by `make web`.

import { copyFileSync, existsSync, mkdirSync, readFileSync, renameSync, rmSync, writeFileSync } from 'node:fs';
import { dirname, join, normalize, relative, resolve } from 'node:path';
import { fileURLToPath } from 'node:url';

const ADDONS = ['controls/OrbitControls.js', 'loaders/GLTFLoader.js'];
const CORE = ['three.module.js', 'three.core.js'];

const here = dirname(fileURLToPath(import.meta.url));
const [modulesDir, outDir] = process.argv.slice(2).map((p) => resolve(p));
if (!modulesDir || !outDir) {
  console.error('usage: node web/build.mjs NODE_MODULES_DIR OUT_DIR');
  process.exit(2);
}
const three = join(modulesDir, 'three');
if (!existsSync(join(three, 'package.json'))) {
  console.error(`error: ${three} is missing; run 'npm ci --prefix build/web' first (make web does)`);
  process.exit(1);
}

// Build into a sibling temp folder and swap it in, so a failed build leaves the old one intact.
const staging = `${outDir}.tmp-${process.pid}`;
rmSync(staging, { recursive: true, force: true });

function copy(from, to) {
  mkdirSync(dirname(to), { recursive: true });
  copyFileSync(from, to);
}

for (const name of CORE) copy(join(three, 'build', name), join(staging, name));
copy(join(three, 'LICENSE'), join(staging, 'THREE-LICENSE'));

// Addons, following their relative imports ('../utils/X.js') transitively.
const addonRoot = join(three, 'examples', 'jsm');
const queue = [...ADDONS];
const seen = new Set();
while (queue.length) {
  const rel = normalize(queue.pop());
  if (seen.has(rel)) continue;
  seen.add(rel);
  const source = join(addonRoot, rel);
  copy(source, join(staging, 'addons', rel));
  const text = readFileSync(source, 'utf-8');
  for (const match of text.matchAll(/(?:from|import)\s*['"](\.{1,2}\/[^'"]+)['"]/g)) {
    queue.push(relative(addonRoot, join(dirname(source), match[1])));
  }
}

copy(join(here, '..', 'engines', 'web', 'fracture_runtime.js'), join(staging, 'fracture_runtime.js'));
copy(join(here, '..', 'engines', 'web', 'fracture_aligned.js'), join(staging, 'fracture_aligned.js')); // aligned fracture
const version = JSON.parse(readFileSync(join(three, 'package.json'), 'utf-8')).version;
writeFileSync(join(staging, 'BUILD.json'), JSON.stringify({ three: version, addons: [...seen].sort() }, null, 2) + '\n');

rmSync(outDir, { recursive: true, force: true });
renameSync(staging, outDir);
console.log(`web: three ${version} and ${seen.size} addon files -> ${relative(process.cwd(), outDir)}`);
