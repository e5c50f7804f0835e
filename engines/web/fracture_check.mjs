#!/usr/bin/env node
// Conformance driver of fracture_runtime.js (Node.js 18+): the same line protocol as the other
// engine readers' drivers (tests/engine_support.py), so one comparison checks them all.
//
//   node fracture_check.mjs [--names] [--skip-crc] [--jump-table] HEADER.fracture.json BINARY.fracture.bin < impacts
//   node fracture_check.mjs --bench=ROUNDS [--jump-table] HEADER BINARY < impacts
//
// Impacts in, one per line: 7 tokens, the IEEE-754 bits of point x y z, impulse x y z and the
// threshold as 16 hex digits (big-endian), or "-" for the file's default threshold.
// Answers out, one per line:
//   ok <site> <num_groups> g <groups...> b <broken edge indices...> a <alpha bits...> d <displacement bits...>
//   error <reason>
// A file that does not load prints "load-error <reason>" and exits with status 2; --names first
// prints "names" and the hex of each fragment name's UTF-8 bytes ("-" for an empty name).
// Each impact is also projected with { displacement: false } (the jump table's path when
// --jump-table built one): an answer that differs prints "error inconsistent".
// --bench=ROUNDS times every impact ROUNDS times (process.hrtime around each project call with
// { displacement: false }, after one untimed round) and prints "median_ns <x> p99_ns <x> calls <n>".

import { readFileSync } from 'node:fs';

import { parseRuntime } from './fracture_runtime.js';

const scratch = new DataView(new ArrayBuffer(8));

function fromBits(hex) {
  if (!/^[0-9a-fA-F]{16}$/.test(hex)) throw new Error(`bad token ${JSON.stringify(hex)}`);
  scratch.setBigUint64(0, BigInt(`0x${hex}`));
  return scratch.getFloat64(0);
}

function toBits(value) {
  scratch.setFloat64(0, value);
  return scratch.getBigUint64(0).toString(16).padStart(16, '0');
}

function hexName(name) {
  return Buffer.from(name, 'utf-8').toString('hex') || '-';
}

function answer(runtime, line) {
  const tokens = line.trim().split(/\s+/);
  if (tokens.length !== 7) return `error expected 7 tokens, got ${tokens.length}`;
  let result;
  try {
    const values = tokens.slice(0, 6).map(fromBits);
    const threshold = tokens[6] === '-' ? undefined : fromBits(tokens[6]);
    result = runtime.project(values.slice(0, 3), values.slice(3, 6), threshold);
    const quick = runtime.project(values.slice(0, 3), values.slice(3, 6), threshold, { displacement: false });
    if (quick.site !== result.site || quick.numGroups !== result.numGroups ||
        quick.groups.join() !== result.groups.join() || quick.broken.join() !== result.broken.join()) {
      return 'error inconsistent';
    }
  } catch (err) {
    return `error ${err.message}`;
  }
  const broken = [];
  result.broken.forEach((b, m) => { if (b) broken.push(m); });
  return ['ok', result.site, result.numGroups, 'g', ...result.groups, 'b', ...broken,
    'a', ...Array.from(result.alpha, toBits), 'd', ...Array.from(result.displacement, toBits)].join(' ');
}

function bench(runtime, rounds, input) {
  const hits = [];
  for (const line of input.split('\n')) {
    const tokens = line.trim().split(/\s+/);
    if (tokens.length !== 7) continue;
    const values = tokens.slice(0, 6).map(fromBits);
    hits.push([values.slice(0, 3), values.slice(3, 6), tokens[6] === '-' ? undefined : fromBits(tokens[6])]);
  }
  const times = [];
  for (let r = 0; r <= rounds; r++) {  // round 0 warms up the JIT, not timed
    for (const [point, impulse, threshold] of hits) {
      const t0 = process.hrtime.bigint();
      runtime.project(point, impulse, threshold, { displacement: false });
      const t1 = process.hrtime.bigint();
      if (r > 0) times.push(Number(t1 - t0));
    }
  }
  times.sort((a, b) => a - b);
  return `median_ns ${times[times.length >> 1]} p99_ns ${times[Math.floor(0.99 * (times.length - 1))]} calls ${times.length}`;
}

function main(argv) {
  const flags = argv.filter((a) => a.startsWith('--'));
  const [headerPath, binaryPath] = argv.filter((a) => !a.startsWith('--'));
  if (!headerPath || !binaryPath) {
    process.stderr.write('usage: node fracture_check.mjs [--names] [--skip-crc] [--jump-table] [--bench=ROUNDS] HEADER BINARY < impacts\n');
    return 64;
  }
  let runtime;
  try {
    runtime = parseRuntime(new Uint8Array(readFileSync(headerPath)), readFileSync(binaryPath),
      { checkCrc: !flags.includes('--skip-crc'), jumpTable: flags.includes('--jump-table') });
  } catch (err) {
    process.stdout.write(`load-error ${err.message}\n`);
    return 2;
  }
  const rounds = flags.find((f) => f.startsWith('--bench='));
  if (rounds) {
    process.stdout.write(`${bench(runtime, Number(rounds.slice('--bench='.length)), readFileSync(0, 'utf-8'))}\n`);
    return 0;
  }
  const out = [];
  if (flags.includes('--names')) out.push(['names', ...runtime.fragmentNames.map(hexName)].join(' '));
  const input = readFileSync(0, 'utf-8');
  for (const line of input.split('\n')) if (line.trim()) out.push(answer(runtime, line));
  process.stdout.write(out.map((l) => `${l}\n`).join(''));
  return 0;
}

process.exitCode = main(process.argv.slice(2));
