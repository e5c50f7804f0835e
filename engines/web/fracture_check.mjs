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
//
// Damage states (docs/FORMAT.md section 12): an input line "state -" starts a sequence on a fresh
// state, "state <e healths as 16 hex digits>" on that state ("state-error <reason>" if it is refused);
// the impacts after it are hits on the state, each answered as above and followed by
//   health <e healths as 16 hex digits>     (after a refused hit too: the state it left)
// On a file with feature "anchors" or "damage", and in a sequence, every "ok" line is followed by
//   more c <cracked bond indices...> n <anchored flag of each fragment...>
// Levels (docs/FORMAT.md section 14), the lines of tests/levels_support.py: "body <b> <impact>" (a stateless
// impact on body b's view), "object new" / "object <health bits...>" (the object state), "hit <struck> <impact>"
// (hitPiece, answered "piece ok ..." or "piece error ... h ...", with every piece after the hit); --children
// prints "children <hex of each child name...>".
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

function indices(flags) {
  const out = [];
  flags.forEach((flag, m) => { if (flag) out.push(m); });
  return out;
}

function same(a, b) {
  return a.site === b.site && a.numGroups === b.numGroups && a.groups.join() === b.groups.join() &&
    a.broken.join() === b.broken.join() && a.cracked.join() === b.cracked.join() && a.anchored.join() === b.anchored.join();
}

// The answer lines of one impact: stateless (state null) or a hit on `state`, checked against the
// same call with { displacement: false } (on a copy of the state for a hit).
function answer(runtime, line, state, structured) {
  const tokens = line.trim().split(/\s+/);
  if (tokens.length !== 7) return [`error expected 7 tokens, got ${tokens.length}`];
  let result;
  try {
    const values = tokens.slice(0, 6).map(fromBits);
    const threshold = tokens[6] === '-' ? undefined : fromBits(tokens[6]);
    const [point, impulse] = [values.slice(0, 3), values.slice(3, 6)];
    let quick;
    if (state === null) {
      result = runtime.project(point, impulse, threshold);
      quick = runtime.project(point, impulse, threshold, { displacement: false });
    } else {
      quick = runtime.hit(Float64Array.from(state), point, impulse, threshold, { displacement: false });
      result = runtime.hit(state, point, impulse, threshold);
    }
    if (!same(quick, result)) return ['error inconsistent'];
  } catch (err) {
    return [`error ${err.message}`];
  }
  const lines = [['ok', result.site, result.numGroups, 'g', ...result.groups, 'b', ...indices(result.broken),
    'a', ...Array.from(result.alpha, toBits), 'd', ...Array.from(result.displacement, toBits)].join(' ')];
  if (structured) lines.push(['more', 'c', ...indices(result.cracked), 'n', ...result.anchored].join(' '));
  return lines;
}

// A "hit" line: hitPiece on the object state, answered with every piece of the object after it.
function pieceAnswer(runtime, tokens, object) {
  const health = () => ['h', ...Array.from(object, toBits)].join(' ');
  let hit;
  try {
    if (tokens.length !== 9) throw new Error(`expected 9 tokens, got ${tokens.length}`);
    const values = tokens.slice(2, 8).map(fromBits);
    const threshold = tokens[8] === '-' ? undefined : fromBits(tokens[8]);
    hit = runtime.hitPiece(object, Number(tokens[1]), values.slice(0, 3), values.slice(3, 6), threshold);
  } catch (err) {
    return `piece error ${err.message.replace(/\s+/g, '_')} ${health()}`;
  }
  const pieces = runtime.objectPieces(object);
  return ['piece ok', hit.body, hit.result.site, hit.childBody, hit.childResult ? hit.childResult.site : -1, hit.split ? 1 : 0,
    'b', ...indices(hit.result.broken), 'c', ...(hit.childResult ? indices(hit.childResult.broken) : []),
    'p', ...pieces.map((piece) => piece.fragments.join(',')), 'y', ...pieces.map((piece) => (piece.anchored ? 1 : 0)),
    health()].join(' ');
}

// Every input line's answers; "state" lines switch to hits on a damage state.
function answerAll(runtime, input) {
  const structured = runtime.anchored !== null || runtime.damage !== null;
  const out = [];
  let state = null;
  let object = runtime.newObjectState();
  for (const line of input.split('\n')) {
    const tokens = line.trim().split(/\s+/).filter(Boolean);
    if (!tokens.length) continue;
    if (tokens[0] === 'object') {
      try {
        const next = tokens[1] === 'new' ? runtime.newObjectState() : Float64Array.from(tokens.slice(1), fromBits);
        runtime.checkObjectState(next);
        object = next;
      } catch (err) {
        out.push(`object-error ${err.message}`);
      }
      continue;
    }
    if (tokens[0] === 'hit') {
      out.push(pieceAnswer(runtime, tokens, object));
      continue;
    }
    if (tokens[0] === 'body') {
      const body = runtime.body(Number(tokens[1]));
      out.push(...answer(body, tokens.slice(2).join(' '), null, body.anchored !== null || body.damage !== null));
      continue;
    }
    if (tokens[0] === 'state') {
      try {
        state = tokens[1] === '-' ? runtime.newState() : Float64Array.from(tokens.slice(1), fromBits);
        runtime.checkState(state);
      } catch (err) {
        state = null;
        out.push(`state-error ${err.message}`);
      }
      continue;
    }
    out.push(...answer(runtime, line, state, structured || state !== null));
    if (state !== null) out.push(['health', ...Array.from(state, toBits)].join(' '));
  }
  return out;
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
  if (flags.includes('--children')) {
    const names = [];
    for (let g = runtime.numFragments; g < runtime.numAllFragments; g++) names.push(hexName(runtime.anyFragmentName(g)));
    out.push(['children', ...names].join(' '));
  }
  out.push(...answerAll(runtime, readFileSync(0, 'utf-8')));
  process.stdout.write(out.map((l) => `${l}\n`).join(''));
  return 0;
}

process.exitCode = main(process.argv.slice(2));
