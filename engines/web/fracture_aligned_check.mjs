#!/usr/bin/env node
// Drive fracture_aligned.js from the command line (tests and bench), like engines/c/tools/fracture_aligned_check.c:
//
//   node fracture_aligned_check.mjs [--full] [--time N] HEADER.aligned.json BINARY.aligned.bin < hits
//
// Each input line is a hit `pattern px py pz dx dy dz scale`; each output line one JSON object with the
// same keys as the C driver's. With --time N each hit runs N times and the line gives the median
// microseconds of process CPU time.
import { readFileSync } from 'node:fs';
import { AlignedError, alignedFracture, getPiece, loadAligned } from './fracture_aligned.js';

const args = process.argv.slice(2);
let full = false, repeat = 0;
while (args.length && args[0].startsWith('--')) {
  const flag = args.shift();
  if (flag === '--full') full = true;
  else if (flag === '--time') repeat = Number(args.shift());
  else { console.error(`unknown option ${flag}`); process.exit(2); }
}
if (args.length !== 2) {
  console.error('usage: fracture_aligned_check.mjs [--full] [--time N] HEADER BINARY < hits');
  process.exit(2);
}
let data;
try {
  data = loadAligned(readFileSync(args[0]), readFileSync(args[1]));
} catch (e) {
  if (!(e instanceof AlignedError)) throw e;
  console.log(JSON.stringify({ status: 'error', error: e.name, message: e.message }));
  process.exit(1);
}

const area = (t, o) => {
  const u = [t[o + 8] - t[o], t[o + 9] - t[o + 1], t[o + 10] - t[o + 2]];
  const v = [t[o + 16] - t[o], t[o + 17] - t[o + 1], t[o + 18] - t[o + 2]];
  const x = u[1] * v[2] - u[2] * v[1], y = u[2] * v[0] - u[0] * v[2], z = u[0] * v[1] - u[1] * v[0];
  return 0.5 * Math.sqrt((x * x + y * y) + z * z);
};

function summary(result) {
  return {
    status: 'ok',
    fragments: result.fragments.map((f) => {
      let total = f.materials.length, newArea = 0, interior = 0;
      for (const k of f.wholePieces) total += getPiece(data, k).triangleCount;
      for (let t = 0; t < f.materials.length; t++) {
        const a = area(f.triangles, 24 * t);
        newArea += a;
        if (f.materials[t] === data.interiorMaterial) interior += a;
      }
      return {
        cell: f.cell, volume: f.volume, center_of_mass: f.centerOfMass, whole_pieces: f.wholePieces,
        new_triangles: f.materials.length, triangles: total, new_area: newArea, interior_area: interior,
        parts: f.parts.map((p) => {
          const out = { piece: p.piece, whole: p.whole, vertices: p.whole ? 0 : p.vertices.length / 3,
            faces: p.whole ? 0 : p.isNew.length, volume: p.volume, centroid: p.centroid };
          if (full && !p.whole) {
            out.corners = [];
            for (let i = 0; i < p.vertices.length; i += 3) out.corners.push(Array.from(p.vertices.subarray(i, i + 3)));
            out.loops = [];
            for (let g = 0; g < p.isNew.length; g++) out.loops.push(Array.from(p.loops.subarray(p.loopOffsets[g], p.loopOffsets[g + 1])));
            out.planes = [];
            for (let g = 0; g < p.isNew.length; g++) out.planes.push(Array.from(p.planes.subarray(4 * g, 4 * g + 4)));
            out.new = Array.from(p.isNew);
          }
          return out;
        }),
      };
    }),
  };
}

const lines = readFileSync(0, 'utf-8').split('\n').filter((l) => l.trim());
const out = [];
for (const line of lines) {
  const v = line.trim().split(/\s+/).map(Number);
  const [pattern, px, py, pz, dx, dy, dz, scale] = v;
  let result;
  try {
    result = alignedFracture(data, [px, py, pz], [dx, dy, dz], scale, pattern);
  } catch (e) {
    if (!(e instanceof AlignedError)) throw e;
    out.push(JSON.stringify({ status: 'error', error: e.message }));
    continue;
  }
  if (repeat > 0) {
    const times = [];
    for (let i = 0; i < repeat; i++) {
      const t0 = process.cpuUsage();
      alignedFracture(data, [px, py, pz], [dx, dy, dz], scale, pattern);
      const t = process.cpuUsage(t0);
      times.push(t.user + t.system);
    }
    times.sort((a, b) => a - b);
    out.push(JSON.stringify({ status: 'ok', us: times[repeat >> 1], fragments: result.fragments.length,
      parts: result.fragments.reduce((s, f) => s + f.parts.length, 0),
      triangles: result.fragments.reduce((s, f) => s + f.materials.length, 0) }));
  } else {
    // 17 significant digits, as the C driver prints them
    out.push(JSON.stringify(summary(result)));
  }
}
process.stdout.write(out.join('\n') + (out.length ? '\n' : ''));
