#!/usr/bin/env node
// Command-line driver of fracture_runtime.js, for tests and for scripting:
//
//   node project_cli.mjs < request.json > results.json
//
// request: {"runtime": "path/to/x.fracture.json", "hits": [{"point": [x,y,z], "impulse": [x,y,z],
//           "threshold": number | null | "inf" | "-inf" | "nan"}, ...]}
// (JSON has no infinities, so they come as strings; any value is passed through as-is otherwise.)
// results: {"load_error": "..."} when the file does not parse, else {"results": [one per hit:
//           {"site", "groups", "broken", "alpha", "displacement", "jumps", "num_groups"} or {"error": "..."}]}
// Non-finite outputs are written as the strings "inf", "-inf", "nan".

import { readFileSync } from 'node:fs';
import { dirname, join } from 'node:path';

import { parseRuntime } from './fracture_runtime.js';

const SPECIAL = { inf: Infinity, '+inf': Infinity, '-inf': -Infinity, nan: NaN, infinity: Infinity, '-infinity': -Infinity };

function decodeNumber(value) {
  if (typeof value === 'string' && value.toLowerCase() in SPECIAL) return SPECIAL[value.toLowerCase()];
  if (Array.isArray(value)) return value.map(decodeNumber);
  return value;
}

function encodeNumbers(values) {
  return Array.from(values, (v) => (Number.isFinite(v) ? v : Number.isNaN(v) ? 'nan' : v > 0 ? 'inf' : '-inf'));
}

function load(jsonPath) {
  const headerBytes = readFileSync(jsonPath);
  let uri = null;
  try {
    uri = JSON.parse(headerBytes.toString('utf-8')).buffer.uri;
  } catch {
    uri = null;
  }
  const binary = typeof uri === 'string' && uri !== '' && !uri.includes('/') ? readFileSync(join(dirname(jsonPath), uri)) : new Uint8Array(0);
  return parseRuntime(new Uint8Array(headerBytes), binary);
}

function main() {
  const request = JSON.parse(readFileSync(0, 'utf-8'));
  let runtime;
  try {
    runtime = load(request.runtime);
  } catch (err) {
    process.stdout.write(JSON.stringify({ load_error: `${err.name}: ${err.message}` }) + '\n');
    return;
  }
  const results = (request.hits || []).map((hit) => {
    try {
      const threshold = decodeNumber(hit.threshold);
      const r = runtime.project(decodeNumber(hit.point), decodeNumber(hit.impulse), threshold === null ? undefined : threshold);
      return {
        site: r.site,
        groups: Array.from(r.groups),
        broken: Array.from(r.broken, (b) => b === 1),
        alpha: encodeNumbers(r.alpha),
        displacement: encodeNumbers(r.displacement),
        jumps: encodeNumbers(r.jumps),
        num_groups: r.numGroups,
      };
    } catch (err) {
      return { error: `${err.name}: ${err.message}` };
    }
  });
  process.stdout.write(JSON.stringify({ results }) + '\n');
}

main();
