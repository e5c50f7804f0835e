// fracture_runtime.js: a reader of the fracture-modes runtime file (version 1, and version 2
// with features "stress", the stress criterion of docs/FORMAT.md section 11, "sharing", load
// sharing among the struck fragment's bonds, section 11.1, "anchors" and "damage", structures and
// damage that adds up, section 12, and "levels", fragments that break again, section 14) and the
// realtime impact projection, written from docs/FORMAT.md alone.
//
// A standalone ES module with no dependencies; it runs in browsers and in Node.js (>= 18).
// MIT licence, Copyright (c) fracture developers (see LICENSE next to this file).
//
//   import { parseRuntime, loadRuntime } from './fracture_runtime.js';
//   const rt = parseRuntime(headerJsonTextOrObject, binaryArrayBufferOrUint8Array);
//   const hit = rt.project([x, y, z], [nx, ny, nz], threshold);  // threshold optional
//   hit.groups  // Int32Array(p): smallest fragment index of each fragment's group
//
// Damage that adds up (feature "damage"): keep one state per object and hit it.
//   const state = rt.newState();                             // Float64Array(e), every bond at health 1
//   const res = rt.hit(state, [x, y, z], [nx, ny, nz]);      // updates state in place
//   res.broken, res.cracked (per bond), res.anchored (per fragment: its group holds on to the world)
//
// For many hits per second (a game rather than a viewer): parseRuntime(..., { jumpTable: true })
// tabulates the d = 1 jumps per contact site (docs/FORMAT.md section 4, "Cost"; about 10 * (e + p)
// bytes per site) and rt.project(point, impulse, threshold, { displacement: false }) then finds
// the groups with a bisection and one pass over at most p merges, without the displacements.
//
// Arithmetic is double precision. The projection is scale invariant (docs/FORMAT.md
// section 4): with m = max(|n0|, |n1|, |n2|) the impulse is divided by m, the jumps are
// compared with T / m, and reported values are multiplied back by m, so impulses near
// the limits of double precision give the same groups as moderate ones.

export const FORMAT_NAME = 'fracture-modes-runtime';
export const FORMAT_VERSION = 2;  // the newest version this reader reads
/** The version-2 features this reader implements (docs/FORMAT.md sections 11, 11.1, 12 and 14). */
export const KNOWN_FEATURES = ['anchors', 'damage', 'levels', 'sharing', 'stress'];

// name -> [dtype, number of dimensions]; also the order of the arrays in the binary file.
const ARRAY_LAYOUT = [
  ['sites', 'float32', 2],
  ['B', 'float32', 3],
  ['W', 'float32', 3],
  ['edges', 'int32', 2],
  ['edge_areas', 'float32', 1],
];
// The stress criterion's arrays (docs/FORMAT.md section 11), after the others; only with feature "stress".
const STRESS_LAYOUT = [
  ['site_bonds_ptr', 'int32', 1],
  ['site_bonds', 'int32', 1],
  ['site_bond_gain', 'float32', 2],
  ['bond_strength', 'float32', 1],
];
// Load sharing (docs/FORMAT.md section 11.1), after the stress arrays; only with feature "sharing".
const SHARING_LAYOUT = [['site_fragment', 'int32', 1]];
// Structures (docs/FORMAT.md section 12): the anchored flags with feature "anchors"; the crack
// segments (drawing only, optional in any version-2 file) both or neither.
const ANCHOR_LAYOUT = [['anchored', 'int32', 1]];
const CRACK_LAYOUT = [['crack_ptr', 'int32', 1], ['crack_segments', 'float32', 3]];

/** A runtime file that is malformed, truncated, of another format or inconsistent. */
// Marks a body's view (docs/FORMAT.md section 14.3) that parseRuntime makes itself: version 2 without features.
const VIEW = Symbol('fracture body view');

export class RuntimeFileError extends Error {
  constructor(message) {
    super(message);
    this.name = 'RuntimeFileError';
  }
}

let crcTable = null;

/** CRC-32 (zlib/PNG polynomial) of a Uint8Array, as an unsigned 32-bit number. */
export function crc32(bytes) {
  if (crcTable === null) {
    crcTable = new Uint32Array(256);
    for (let n = 0; n < 256; n++) {
      let c = n;
      for (let k = 0; k < 8; k++) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
      crcTable[n] = c >>> 0;
    }
  }
  let crc = 0xffffffff;
  for (let i = 0; i < bytes.length; i++) crc = crcTable[(crc ^ bytes[i]) & 0xff] ^ (crc >>> 8);
  return (crc ^ 0xffffffff) >>> 0;
}

function fail(message) {
  throw new RuntimeFileError(message);
}

function isCount(value) {
  return Number.isInteger(value) && value >= 0;
}

function asBytes(binary) {
  if (binary instanceof Uint8Array) return binary;
  if (binary instanceof ArrayBuffer) return new Uint8Array(binary);
  if (ArrayBuffer.isView(binary)) return new Uint8Array(binary.buffer, binary.byteOffset, binary.byteLength);
  throw new TypeError('binary must be an ArrayBuffer or a typed array');
}

// FORMAT.md section 1: a runtime header nests 3 levels; deeper than this is refused
// before parsing, so a hostile file cannot exhaust the parser's stack.
const MAX_NESTING = 64;

function nestingDepth(text) {
  let depth = 0;
  let deepest = 0;
  let inString = false;
  for (let i = 0; i < text.length; i++) {
    const c = text.charCodeAt(i);
    if (inString) {
      if (c === 0x5c) i++; // backslash: skip the escaped character
      else if (c === 0x22) inString = false;
    } else if (c === 0x22) {
      inString = true;
    } else if (c === 0x5b || c === 0x7b) {
      depth++;
      if (depth > deepest) deepest = depth;
    } else if (c === 0x5d || c === 0x7d) {
      depth--;
    }
  }
  return deepest;
}

function asHeader(header) {
  if (typeof header === 'string' || header instanceof Uint8Array || header instanceof ArrayBuffer) {
    let text = header;
    try {
      if (typeof header !== 'string') text = new TextDecoder('utf-8', { fatal: true }).decode(asBytes(header));
    } catch (err) {
      return fail(`not a JSON runtime file (${err.message})`);
    }
    if (nestingDepth(text) > MAX_NESTING) fail(`header nests deeper than ${MAX_NESTING} levels`);
    try {
      return JSON.parse(text);
    } catch (err) {
      return fail(`not a JSON runtime file (${err.message})`);
    }
  }
  return header;
}

function checkHeader(h) {
  if (h === null || typeof h !== 'object' || Array.isArray(h) || h.format !== FORMAT_NAME) {
    fail(`not a fracture runtime file (expected "format": "${FORMAT_NAME}")`);
  }
  if (!Number.isInteger(h.version) || h.version < 1 || h.version > FORMAT_VERSION) {
    fail(`runtime file version ${JSON.stringify(h.version)} is not supported (this reader knows 1..${FORMAT_VERSION})`);
  }
  checkFeatures(h);
  if (h.dim !== 1 && h.dim !== 3) fail(`dim must be 1 or 3, got ${JSON.stringify(h.dim)}`);
  const c = h.counts;
  if (!c || typeof c !== 'object' || !['sites', 'modes', 'fragments', 'edges'].every((key) => isCount(c[key]))) {
    fail('counts must hold non-negative integers sites, modes, fragments and edges');
  }
  if (c.sites < 1) fail('there are no contact sites');
  if (c.modes < 1 || c.fragments < 1) fail(`need at least one mode and one fragment, got k = ${c.modes}, p = ${c.fragments}`);
  if (!Array.isArray(h.fragment_names) || !h.fragment_names.every((name) => typeof name === 'string')) {
    fail('fragment_names must be a list of strings');
  }
  if (h.fragment_names.length !== c.fragments) fail(`${h.fragment_names.length} fragment names for ${c.fragments} fragments`);
  if (!Array.isArray(h.transform) || h.transform.length !== 16 || !h.transform.every(Number.isFinite)) {
    fail('transform must be 16 finite numbers');
  }
  if (!Number.isFinite(h.default_threshold) || h.default_threshold < 0) {
    fail(`default threshold must be a finite number >= 0, got ${JSON.stringify(h.default_threshold)}`);
  }
  if (!Number.isFinite(h.impact_radius)) fail('impact_radius must be a finite number');
  const b = h.buffer;
  if (!b || typeof b !== 'object' || !isCount(b.byte_length)) fail('buffer.byte_length must be a non-negative integer');
  if (b.crc32 !== undefined && !(Number.isInteger(b.crc32) && b.crc32 >= 0 && b.crc32 <= 0xffffffff)) {
    fail('buffer.crc32 must be an unsigned 32-bit integer');
  }
  checkUri(b.uri);
  if (!h.arrays || typeof h.arrays !== 'object') fail('the header has no arrays table');
  if (stressOf(h) && !isCount(c.site_bonds)) fail('counts.site_bonds must be a non-negative integer');
  if (featuresOf(h).includes('damage')) checkDamage(h.damage);
  if (featuresOf(h).includes('sharing')) checkSharing(h.sharing);
}

// Section 11.1: the sharing object's concentration kappa, a finite number > 0.
function checkSharing(sharing) {
  if (!sharing || typeof sharing !== 'object' || Array.isArray(sharing)) {
    fail("runtime file lists feature 'sharing' but has no header object 'sharing'");
  }
  const kappa = sharing.concentration;
  if (typeof kappa !== 'number' || !Number.isFinite(kappa) || !(kappa > 0)) {
    fail(`sharing.concentration must be a finite number > 0, got ${typeof kappa === 'number' ? kappa : JSON.stringify(kappa)}`);
  }
}

/** The (checked) header's features; none in version 1. */
function featuresOf(h) {
  return h.version >= 2 ? h.features : [];
}

// Section 12.1: crack level c in (0, 1], damage rate r finite and >= 0.
function checkDamage(damage) {
  if (!damage || typeof damage !== 'object' || Array.isArray(damage)) {
    fail("runtime file lists feature 'damage' but has no header object 'damage'");
  }
  const { crack_level: c, damage_rate: r } = damage;
  if (!Number.isFinite(c) || !(c > 0 && c <= 1)) fail(`damage.crack_level must be a number in (0, 1], got ${JSON.stringify(c)}`);
  if (!Number.isFinite(r) || r < 0) fail(`damage.damage_rate must be a finite number >= 0, got ${JSON.stringify(r)}`);
}

// Section 11: version 2 lists the features it needs (refused by name when unknown) and a criterion;
// version 1 ignores both keys. Like the reference reader, a file that lists "stress" must use
// criterion "stress" (the stress arrays come with the criterion).
function checkFeatures(h) {
  if (h.version < 2) return;
  const features = h.features === undefined ? [] : h.features;
  if (!Array.isArray(features) || !features.every((f) => typeof f === 'string')) {
    fail("runtime header 'features' must be a list of strings");
  }
  if (features.length === 0 && !h[VIEW]) fail(`runtime file version ${h.version} lists no features; a file without any is version 1`);
  for (const name of features) {
    if (!KNOWN_FEATURES.includes(name)) fail(`runtime file needs feature '${name}', which this reader does not implement`);
  }
  const criterion = h.criterion === undefined ? 'modes' : h.criterion;
  if (typeof criterion !== 'string') fail("runtime header 'criterion' must be a string");
  if (criterion !== 'modes' && criterion !== 'stress') {
    fail(`runtime file needs criterion '${criterion}', which this reader does not implement`);
  }
  const stress = features.includes('stress');
  if (features.includes('sharing') && criterion !== 'stress') {
    fail("runtime file has feature 'sharing' without criterion 'stress'");
  }
  if (criterion === 'stress' && !stress) fail("runtime file has criterion 'stress' but does not list feature 'stress'");
  if (criterion !== 'stress' && stress) {
    fail("runtime file lists feature 'stress' but its criterion is 'modes' (the stress arrays come with criterion 'stress')");
  }
}

/** Whether a (checked) header uses the stress criterion. */
function stressOf(h) {
  return h.version >= 2 && h.criterion === 'stress';
}

/** Throw unless uri is a plain file name in the header's folder (docs/FORMAT.md section 1). */
export function checkUri(uri) {
  if (typeof uri !== 'string' || uri === '' || uri === '.' || uri === '..' || /[/\\:]/.test(uri)) {
    fail(`buffer.uri must be a plain file name next to the header, got ${JSON.stringify(uri)}`);
  }
}

function expectedShapes(h) {
  const { sites: s, modes: k, fragments: p, edges: e } = h.counts;
  const d = h.dim;
  const nnz = h.counts.site_bonds;
  // The number of crack segments is the array's own (counts.crack_segments must then agree with it).
  const segments = h.arrays.crack_segments;
  const n = segments && Array.isArray(segments.shape) ? segments.shape[0] : -1;
  return { sites: [s, 3], B: [s, k, d], W: [k, p, d], edges: [e, 2], edge_areas: [e],
    site_bonds_ptr: [s + 1], site_bonds: [nnz], site_bond_gain: [nnz, 3], bond_strength: [e], site_fragment: [s],
    anchored: [p], crack_ptr: [e + 1], crack_segments: [n, 2, 3] };
}

function readArray(name, dtype, ndim, entry, view, shapes) {
  if (!entry || typeof entry !== 'object') fail(`runtime header has no entry for array '${name}'`);
  if (entry.dtype !== dtype) fail(`array '${name}' has dtype ${JSON.stringify(entry.dtype)}, expected "${dtype}"`);
  const shape = entry.shape;
  if (!Array.isArray(shape) || shape.length !== ndim || !shape.every(isCount)) {
    fail(`array '${name}' has shape ${JSON.stringify(shape)}, expected ${ndim} non-negative integers`);
  }
  const offset = entry.byte_offset;
  const length = entry.byte_length;
  const count = shape.reduce((a, n) => a * n, 1);
  if (!isCount(offset) || !isCount(length) || length !== 4 * count) {
    fail(`array '${name}' has shape ${JSON.stringify(shape)} and ${length} bytes, which do not agree`);
  }
  if (offset % 16 !== 0 || offset + length > view.byteLength) {
    fail(`array '${name}' lies outside the binary file (offset ${offset}, length ${length})`);
  }
  if (shape.join(',') !== shapes[name].join(',')) {
    fail(`array ${name} has shape ${JSON.stringify(shape)}, expected ${JSON.stringify(shapes[name])} from counts and dim`);
  }
  // DataView reads are little-endian whatever the platform; copying also drops any alignment concern.
  if (dtype === 'int32') {
    const out = new Int32Array(count);
    for (let i = 0; i < count; i++) out[i] = view.getInt32(offset + 4 * i, true);
    return out;
  }
  const out = new Float64Array(count);
  for (let i = 0; i < count; i++) {
    const value = view.getFloat32(offset + 4 * i, true);
    if (!Number.isFinite(value)) fail(`array ${name} has non-finite values`);
    out[i] = value;
  }
  return out;
}

/**
 * Parse a runtime file from its header and binary bytes, validating both.
 *
 * @param {string|object|Uint8Array|ArrayBuffer} header  the .fracture.json text, bytes or parsed object
 * @param {ArrayBuffer|Uint8Array} binary  the .fracture.bin bytes
 * @param {{checkCrc?: boolean, jumpTable?: boolean}} [options]  checkCrc (default true): compare buffer.crc32
 *   when present; jumpTable (default false): for a d = 1 file, build the per-site jump table that makes
 *   project(..., { displacement: false }) fast (see the top of this file)
 * @returns {FractureRuntime}
 * @throws {RuntimeFileError} on any inconsistency (sizes, offsets, shapes, counts, indices, checksum)
 */
export function parseRuntime(header, binary, options = {}) {
  const h = asHeader(header);
  if (options[VIEW]) h[VIEW] = true;
  checkHeader(h);
  const bytes = asBytes(binary);
  if (bytes.byteLength !== h.buffer.byte_length) {
    fail(`binary file has ${bytes.byteLength} bytes but the header says ${h.buffer.byte_length} (truncated or from another bake)`);
  }
  if (options.checkCrc !== false && h.buffer.crc32 !== undefined && crc32(bytes) !== h.buffer.crc32) {
    fail('binary file does not match its header (crc32 differs; from another bake?)');
  }
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const shapes = expectedShapes(h);
  const arrays = {};
  for (const [name, dtype, ndim] of ARRAY_LAYOUT) arrays[name] = readArray(name, dtype, ndim, h.arrays[name], view, shapes);
  const p = h.counts.fragments;
  const edges = arrays.edges;
  for (let m = 0; m < edges.length; m += 2) {
    if (!(edges[m] >= 0 && edges[m] < edges[m + 1] && edges[m + 1] < p)) fail(`edges must be pairs (P, Q) with 0 <= P < Q < ${p}`);
  }
  if (stressOf(h)) {
    for (const [name, dtype, ndim] of STRESS_LAYOUT) arrays[name] = readArray(name, dtype, ndim, h.arrays[name], view, shapes);
    checkStress(arrays, h.counts.sites, h.counts.edges);
    if (featuresOf(h).includes('sharing')) {
      const [name, dtype, ndim] = SHARING_LAYOUT[0];
      if (!h.arrays[name]) fail("the feature 'sharing' needs the array site_fragment");
      arrays[name] = readArray(name, dtype, ndim, h.arrays[name], view, shapes);
      if (!arrays[name].every((f) => f >= 0 && f < p)) fail(`site_fragment must be fragment indices in 0..${p - 1}`);
    }
  }
  readStructure(h, arrays, view, shapes);
  const runtime = new FractureRuntime(h, arrays);
  if (featuresOf(h).includes('levels')) runtime._readLevels(h, view, options);
  // Not with "damage": every hit then updates a state from each bond's measure, which the table does not keep.
  if (options.jumpTable && runtime.criterion === 'modes' && runtime.dim === 1 && !runtime.damage && runtime.numEdges > 0 &&
      runtime.numEdges <= 0xffff && runtime.numFragments <= 0x7fff) runtime._buildJumpTable();
  return runtime;
}

// Section 11: site_bonds_ptr starts at 0, never decreases and ends at nnz; site_bonds are edge indices,
// strictly ascending within a site; bond_strength >= 0 (readArray checked that every float is finite).
function checkStress(arrays, s, e) {
  const { site_bonds_ptr: ptr, site_bonds: bonds, bond_strength: strength } = arrays;
  const nnz = bonds.length;
  let ok = ptr[0] === 0 && ptr[s] === nnz;
  for (let v = 0; ok && v < s; v++) ok = ptr[v + 1] >= ptr[v];
  if (!ok) fail(`site_bonds_ptr must start at 0, never decrease and end at ${nnz}`);
  for (let v = 0; v < s; v++) {
    for (let j = ptr[v]; j < ptr[v + 1]; j++) {
      if (!(bonds[j] >= 0 && bonds[j] < e)) fail(`site_bonds must be bond indices in 0..${e - 1}`);
      if (j > ptr[v] && bonds[j] <= bonds[j - 1]) fail('site_bonds must be strictly ascending within each site');
    }
  }
  if (!strength.every((x) => x >= 0)) fail('bond_strength must be >= 0');
}

// Section 12.2: anchored (p,) of 0/1 with feature "anchors"; crack_ptr (e + 1) from 0, never decreasing,
// to n and crack_segments (n, 2, 3), finite, both or neither (read in any version-2 file: drawing data).
function readStructure(h, arrays, view, shapes) {
  if (h.version < 2) return;
  if (featuresOf(h).includes('anchors')) {
    const [name, dtype, ndim] = ANCHOR_LAYOUT[0];
    const anchored = readArray(name, dtype, ndim, h.arrays[name], view, shapes);
    if (!anchored.every((a) => a === 0 || a === 1)) fail('array anchored must hold only 0 and 1');
    arrays.anchored = anchored;
  }
  const missing = CRACK_LAYOUT.filter(([name]) => h.arrays[name] === undefined).map(([name]) => name);
  if (missing.length === CRACK_LAYOUT.length) return;
  if (missing.length) fail(`the crack arrays come together: ${missing.join(', ')} missing`);
  for (const [name, dtype, ndim] of CRACK_LAYOUT) arrays[name] = readArray(name, dtype, ndim, h.arrays[name], view, shapes);
  const ptr = arrays.crack_ptr;
  const n = arrays.crack_segments.length / 6;
  let ok = ptr[0] === 0 && ptr[ptr.length - 1] === n;
  for (let m = 1; ok && m < ptr.length; m++) ok = ptr[m] >= ptr[m - 1];
  if (!ok) fail(`crack_ptr must start at 0, never decrease and end at ${n}`);
  const count = h.counts.crack_segments;
  // Present with the crack arrays, as counts.collision_parts with the game-ready arrays (docs/FORMAT.md 12.1).
  if (count !== n) fail(`counts.crack_segments is ${JSON.stringify(count)} but crack_segments has ${n}`);
}

/**
 * Fetch and parse a runtime file by the URL of its .fracture.json (browsers, or Node.js 18+ with fetch).
 * The binary file is found through the header's buffer.uri, relative to the header's URL.
 */
export async function loadRuntime(jsonUrl, fetchFn = globalThis.fetch) {
  const response = await fetchFn(jsonUrl);
  if (!response.ok) throw new RuntimeFileError(`cannot fetch ${jsonUrl} (HTTP ${response.status})`);
  const header = asHeader(await response.text());
  const uri = header && header.buffer && header.buffer.uri;
  checkUri(uri);
  const base = new URL(jsonUrl, globalThis.location ? globalThis.location.href : undefined);
  const binUrl = new URL(encodeURIComponent(uri), base);
  binUrl.search = base.search;  // keep a cache-busting query
  const binResponse = await fetchFn(binUrl.href);
  if (!binResponse.ok) throw new RuntimeFileError(`cannot fetch ${binUrl.href} (HTTP ${binResponse.status})`);
  return parseRuntime(header, await binResponse.arrayBuffer());
}

function vector3(value, name) {
  let xyz = value;
  if (value && !Array.isArray(value) && !ArrayBuffer.isView(value) && typeof value === 'object' && 'x' in value) {
    xyz = [value.x, value.y, value.z];
  }
  if (!xyz || xyz.length !== 3) throw new TypeError(`${name} must be three numbers`);
  const out = [Number(xyz[0]), Number(xyz[1]), Number(xyz[2])];
  for (let c = 0; c < 3; c++) {
    if (typeof xyz[c] !== 'number' || !Number.isFinite(out[c])) {
      throw new RangeError(`${name} must be three finite numbers, got ${JSON.stringify(Array.from(xyz))}`);
    }
  }
  return out;
}

/** A parsed runtime file: counts, names and arrays (float values widened to double), and the projection. */
export class FractureRuntime {
  constructor(header, arrays) {
    this.header = header;
    this.dim = header.dim;
    this.numSites = header.counts.sites;
    this.numModes = header.counts.modes;
    this.numFragments = header.counts.fragments;
    this.numEdges = header.counts.edges;
    this.fragmentNames = header.fragment_names.slice();
    this.defaultThreshold = header.default_threshold;
    this.impactRadius = header.impact_radius;
    this.transform = header.transform.slice();
    this.sites = arrays.sites;        // (s, 3)
    this.B = arrays.B;                // (s, k, d)
    this.W = arrays.W;                // (k, p, d)
    this.edges = arrays.edges;        // (e, 2) Int32Array
    this.edgeAreas = arrays.edge_areas;  // (e,)
    // How a hit decides which bonds break: 'modes' (section 4) or 'stress' (section 11, with the arrays below).
    this.criterion = stressOf(header) ? 'stress' : 'modes';
    this.siteBondsPtr = arrays.site_bonds_ptr || null;  // (s + 1,) Int32Array: site v's entries ptr[v] .. ptr[v+1]-1
    this.siteBonds = arrays.site_bonds || null;         // (nnz,) Int32Array: the bond (edge) of each entry
    this.siteBondGain = arrays.site_bond_gain || null;  // (nnz, 3) G: tensile force per unit impulse along x, y, z
    this.bondStrength = arrays.bond_strength || null;   // (e,) S
    // Section 11.1, feature "sharing": kappa and the fragment each site loads (null without the feature);
    // the bonds of each fragment j, by increasing index, are fragmentBonds[fragmentBondsPtr[j] .. [j+1]-1].
    this.sharing = arrays.site_fragment ? { concentration: header.sharing.concentration } : null;
    this.siteFragment = arrays.site_fragment || null;   // (s,) Int32Array
    if (this.sharing) this._buildFragmentBonds();
    // Section 12: the version-2 features, the fragments bonded to the world, the damage parameters and the
    // crack segments (drawing only). Null (features: empty) when the file does not have them.
    this.features = featuresOf(header).slice();
    this.anchored = arrays.anchored || null;            // (p,) Int32Array, 1: bonded to the world
    this.damage = this.features.includes('damage')
      ? { crackLevel: header.damage.crack_level, damageRate: header.damage.damage_rate } : null;
    this.crackPtr = arrays.crack_ptr || null;           // (e + 1,) Int32Array: bond e's segments ptr[e] .. ptr[e+1]-1
    this.crackSegments = arrays.crack_segments || null; // (n, 2, 3): segment i is [6i .. 6i+5], model space
    // c and q = r / (1 - c) of section 12.4, once per file (q = 0 when c = 1); a file without "damage"
    // acts as c = 1, r = 0, so a state given to hit() only remembers broken bonds.
    this.crackLevel = this.damage ? this.damage.crackLevel : 1;
    this.damageFactor = this.damage && this.crackLevel !== 1 ? this.damage.damageRate / (1 - this.crackLevel) : 0;
    this.hasJumpTable = false;
    this._buildKdTree();
  }

  /** Index of the contact site nearest to point (ties: the smallest index). */
  nearestSite(point) {
    const [x, y, z] = vector3(point, 'point');
    return this._nearest(x, y, z);
  }

  // k-d tree over the sites: node n is kdNodes[4n..4n+3] = begin, end, left, right (left < 0: a leaf)
  // over kdIndex[begin, end), with its exact bounding box kdBoxes[6n..6n+5] = lo xyz, hi xyz.
  _buildKdTree() {
    const s = this.numSites;
    const sites = this.sites;
    const capacity = 4 * Math.floor(s / KD_LEAF) + 2;  // a leaf holds at least KD_LEAF / 2 sites
    this.kdIndex = new Int32Array(s);
    this.kdNodes = new Int32Array(4 * capacity);
    this.kdBoxes = new Float64Array(6 * capacity);
    for (let i = 0; i < s; i++) this.kdIndex[i] = i;
    let count = 0;
    const build = (begin, end) => {
      const id = count++;
      let axis = 0;
      for (let c = 0; c < 3; c++) {
        let lo = Infinity;
        let hi = -Infinity;
        for (let i = begin; i < end; i++) {
          const v = sites[3 * this.kdIndex[i] + c];
          if (v < lo) lo = v;
          if (v > hi) hi = v;
        }
        this.kdBoxes[6 * id + c] = lo;
        this.kdBoxes[6 * id + 3 + c] = hi;
        if (hi - lo > this.kdBoxes[6 * id + 3 + axis] - this.kdBoxes[6 * id + axis]) axis = c;
      }
      this.kdNodes[4 * id] = begin;
      this.kdNodes[4 * id + 1] = end;
      this.kdNodes[4 * id + 2] = this.kdNodes[4 * id + 3] = -1;
      if (end - begin <= KD_LEAF) return id;
      const mid = begin + ((end - begin) >> 1);
      // Any split is correct (the boxes are exact): sort the range along the widest axis and halve it.
      const part = Array.from(this.kdIndex.subarray(begin, end));
      part.sort((a, b) => sites[3 * a + axis] - sites[3 * b + axis]);
      this.kdIndex.set(part, begin);
      this.kdNodes[4 * id + 2] = build(begin, mid);
      this.kdNodes[4 * id + 3] = build(mid, end);
      return id;
    };
    build(0, s);
    this.kdPoints = new Float64Array(3 * s);
    for (let i = 0; i < s; i++) for (let c = 0; c < 3; c++) this.kdPoints[3 * i + c] = sites[3 * this.kdIndex[i] + c];
    this.kdStack = new Int32Array(KD_STACK);
    this.kdBounds = new Float64Array(KD_STACK);
  }

  // Squared distance to a node's box, computed like a site's so it never exceeds one inside.
  _boxDistance2(node, x, y, z) {
    const b = this.kdBoxes;
    const o = 6 * node;
    const dx = x < b[o] ? b[o] - x : x > b[o + 3] ? x - b[o + 3] : 0;
    const dy = y < b[o + 1] ? b[o + 1] - y : y > b[o + 4] ? y - b[o + 4] : 0;
    const dz = z < b[o + 2] ? b[o + 2] - z : z > b[o + 5] ? z - b[o + 5] : 0;
    return dx * dx + dy * dy + dz * dz;
  }

  // Section 4 step 1: a box is skipped only when strictly farther than the best site so far, and
  // equal distances keep the smallest index, so the answer is brute force's, ties included.
  _nearest(x, y, z) {
    const { kdNodes: nodes, kdPoints: points, kdIndex: index, kdStack: stack, kdBounds: bounds } = this;
    let top = 1;
    let best = Infinity;
    let bestIndex = 0x7fffffff;
    stack[0] = 0;
    bounds[0] = this._boxDistance2(0, x, y, z);
    while (top > 0) {
      top--;
      if (bounds[top] > best) continue;
      const node = stack[top];
      const left = nodes[4 * node + 2];
      const right = nodes[4 * node + 3];
      if (left < 0) {
        for (let i = nodes[4 * node]; i < nodes[4 * node + 1]; i++) {
          const dx = points[3 * i] - x;
          const dy = points[3 * i + 1] - y;
          const dz = points[3 * i + 2] - z;
          const d2 = dx * dx + dy * dy + dz * dz;
          if (d2 < best || (d2 === best && index[i] < bestIndex)) {
            best = d2;
            bestIndex = index[i];
          }
        }
        continue;
      }
      const a = this._boxDistance2(left, x, y, z);
      const b = this._boxDistance2(right, x, y, z);
      stack[top] = a <= b ? right : left;  // pushed first: the nearer box is searched first
      bounds[top++] = a <= b ? b : a;
      stack[top] = a <= b ? left : right;
      bounds[top++] = a <= b ? a : b;
    }
    return bestIndex;
  }

  // The d = 1 jump table (docs/FORMAT.md section 4, "Cost"): per site v, |J[v, m]| ascending with
  // J[v, m] = sum over i of B[v, i] (W[i, P] - W[i, Q]) (|jump'| = |n'| |J[v, m]|, and x -> |n'| x
  // rounds monotonically, so the edges that hold are a prefix of the row), and the merges of
  // Kruskal's algorithm over that row, whose clusters are the groups (p entries per site).
  _buildJumpTable() {
    const { numSites: s, numModes: k, numFragments: p, numEdges: e, edges, B, W } = this;
    const diff = new Float64Array(e * k);
    for (let m = 0; m < e; m++) {
      for (let i = 0; i < k; i++) diff[m * k + i] = W[i * p + edges[2 * m]] - W[i * p + edges[2 * m + 1]];
    }
    this.jumps = new Float64Array(s * e);
    this.jumpEdge = new Uint16Array(s * e);
    this.mergeAt = new Uint16Array(s * p);
    this.mergeChild = new Uint16Array(2 * s * p);
    this.mergeLabel = new Int32Array(s * p);
    const keys = new Float64Array(e);
    const order = new Uint16Array(e);
    const uf = new Int32Array(p);
    const cluster = new Int32Array(p);
    let count = 0;
    for (let v = 0; v < s; v++) {
      for (let m = 0; m < e; m++) {
        let sum = 0;
        for (let i = 0; i < k; i++) sum += B[v * k + i] * diff[m * k + i];
        keys[m] = Math.abs(sum);
        order[m] = m;
      }
      order.sort((a, b) => keys[a] - keys[b]);  // ties in any order: they hold or break together
      const row = v * e;
      const at = v * p;
      for (let m = 0; m < e; m++) {
        this.jumps[row + m] = keys[order[m]];
        this.jumpEdge[row + m] = order[m];
      }
      for (let j = 0; j < p; j++) uf[j] = cluster[j] = j;
      count = 0;
      for (let pos = 0; pos < e; pos++) {
        const a = root(uf, edges[2 * order[pos]]);
        const b = root(uf, edges[2 * order[pos] + 1]);
        if (a === b) continue;
        const lo = Math.min(a, b);
        this.mergeAt[at + count] = pos;
        this.mergeChild[2 * (at + count)] = cluster[a];
        this.mergeChild[2 * (at + count) + 1] = cluster[b];
        this.mergeLabel[at + count] = lo;  // roots are their component's smallest fragment
        uf[Math.max(a, b)] = lo;
        cluster[lo] = p + count++;
      }
    }
    this.merges = count;  // the same for every site: p minus the whole graph's number of groups
    this.mergeLabels = new Int32Array(2 * p);  // scratch of _tableGroups
    this.hasJumpTable = true;
  }

  // Steps 5-6 with the jump table: the edges that hold are the row's first `holding`, the merges done
  // the first `done`; top-down over those (a merge's parent comes later), each passes its label on to
  // its two children (labels[0, p): fragments, labels[p + r]: merge r).
  _tableGroups(site, length, limit) {
    const { numEdges: e, numFragments: p, jumps, mergeAt, mergeChild } = this;
    const row = site * e;
    const at = site * p;
    let lo = 0;
    let hi = e;
    while (lo < hi) {
      const mid = (lo + hi) >> 1;
      if (length * jumps[row + mid] <= limit) lo = mid + 1;
      else hi = mid;
    }
    const holding = lo;
    lo = 0;
    hi = this.merges;
    while (lo < hi) {
      const mid = (lo + hi) >> 1;
      if (mergeAt[at + mid] < holding) lo = mid + 1;
      else hi = mid;
    }
    const done = lo;
    const { mergeLabels: labels, mergeLabel, jumpEdge } = this;
    for (let j = 0; j < p; j++) labels[j] = j;
    for (let r = 0; r < done; r++) labels[p + r] = mergeLabel[at + r];
    for (let r = done - 1; r >= 0; r--) {
      const value = labels[p + r];
      labels[mergeChild[2 * (at + r)]] = value;
      labels[mergeChild[2 * (at + r) + 1]] = value;
    }
    const broken = new Uint8Array(e).fill(1);
    for (let i = 0; i < holding; i++) broken[jumpEdge[row + i]] = 0;
    return { broken, groups: labels.slice(0, p), numGroups: p - done };
  }

  /** Mode coefficients (k) of the unit-max impulse nUnit at site v. */
  _alpha(v, nUnit) {
    const { numModes: k, dim: d, B } = this;
    const alpha = new Float64Array(k);
    const base = v * k * d;
    if (d === 1) {
      const norm = Math.sqrt(nUnit[0] * nUnit[0] + nUnit[1] * nUnit[1] + nUnit[2] * nUnit[2]);
      for (let i = 0; i < k; i++) alpha[i] = B[base + i] * norm;
    } else {
      for (let i = 0; i < k; i++) {
        const o = base + 3 * i;
        alpha[i] = B[o] * nUnit[0] + B[o + 1] * nUnit[1] + B[o + 2] * nUnit[2];
      }
    }
    return alpha;
  }

  /** Fragment displacements (p * d) for mode coefficients alpha. */
  _displacement(alpha) {
    const { numModes: k, numFragments: p, dim: d, W } = this;
    const disp = new Float64Array(p * d);
    for (let i = 0; i < k; i++) {
      const a = alpha[i];
      const row = i * p * d;
      for (let q = 0; q < p * d; q++) disp[q] += a * W[row + q];
    }
    return disp;
  }

  /**
   * Group labels (smallest fragment index per component) of the fragment graph without the broken edges.
   * @param {ArrayLike<boolean|number>} [broken]  per edge; truthy = removed. Omitted: the whole graph.
   */
  groups(broken) {
    const p = this.numFragments;
    const parent = new Int32Array(p);
    for (let j = 0; j < p; j++) parent[j] = j;
    const edges = this.edges;
    for (let m = 0; m < this.numEdges; m++) {
      if (broken && broken[m]) continue;
      const a = root(parent, edges[2 * m]);
      const b = root(parent, edges[2 * m + 1]);
      // The smaller root always wins, so every root is the smallest index of its component.
      parent[Math.max(a, b)] = Math.min(a, b);
    }
    // Parents are smaller than their children: one forward pass turns each entry into its root.
    for (let j = 0; j < p; j++) parent[j] = parent[parent[j]];
    return parent;
  }

  /**
   * Project an impact and group the fragments (docs/FORMAT.md section 4).
   *
   * On a file with feature "damage" this is a hit on a fresh state that is then thrown away (section
   * 12.4), so a bond may also crack; use hit() with a state the game keeps to let damage add up.
   *
   * @param {ArrayLike<number>|{x,y,z}} point  hit point, model space (finite)
   * @param {ArrayLike<number>|{x,y,z}} impulse  impulse vector (finite); same unit as threshold
   * @param {number} [threshold]  toughness >= 0 (+Infinity allowed); default: the file's default_threshold
   * @param {{displacement?: boolean}} [options]  displacement (default true): false leaves displacement
   *   and jumps null, and uses the jump table when parseRuntime built one (much faster on big files)
   * @returns {{site: number, alpha: Float64Array, displacement: Float64Array|null, jumps: Float64Array|null,
   *            broken: Uint8Array, cracked: Uint8Array, anchored: Uint8Array, groups: Int32Array, numGroups: number}}
   *   displacement is (p, d) row-major and jumps (e, d); both, like alpha, for the impulse as given.
   *   cracked (per bond) and anchored (per fragment: 1 when its group holds a fragment bonded to the
   *   world) are all 0 without features "damage" and "anchors".
   */
  project(point, impulse, threshold, options = {}) {
    return this._respond(this.damage ? this.newState() : null, point, impulse, threshold, options);
  }

  /** A fresh damage state (section 12.3): one health per bond, all 1 (Float64Array(e)). */
  newState() {
    return new Float64Array(this.numEdges).fill(1);
  }

  /** Throw unless state is a damage state of this file: a Float64Array of e healths, each finite in [0, 1]. */
  checkState(state) {
    if (!(state instanceof Float64Array) || state.length !== this.numEdges) {
      throw new TypeError(`a damage state must be a Float64Array of ${this.numEdges} bond healths`);
    }
    for (let e = 0; e < state.length; e++) {
      if (!(state[e] >= 0 && state[e] <= 1)) {  // also refuses NaN
        throw new RangeError(`a damage state holds healths in [0, 1]; bond ${e} has ${state[e]}`);
      }
    }
  }

  /**
   * One hit on a damage state (docs/FORMAT.md section 12.4): updates state in place and answers like
   * project() for the state after the hit: broken lists every broken bond (this hit's and earlier ones'),
   * cracked the bonds that hold but are cracked (loaded above the crack level by this hit, or weakened
   * earlier), groups and anchored follow from the bonds that are not broken. World bonds never break.
   * Invalid inputs or state throw and leave the state as it was. Works on any file: without feature
   * "damage" a state only remembers which bonds broke.
   *
   * @param {Float64Array} state  from newState() or stateFromBytes(); updated in place
   * @param point, impulse, threshold, options  as project()
   */
  hit(state, point, impulse, threshold, options = {}) {
    this.checkState(state);
    return this._respond(state, point, impulse, threshold, options);
  }

  /** A state as the bytes a game saves: e little-endian doubles. */
  stateToBytes(state) {
    this.checkState(state);
    const bytes = new Uint8Array(8 * state.length);
    const view = new DataView(bytes.buffer);
    for (let e = 0; e < state.length; e++) view.setFloat64(8 * e, state[e], true);
    return bytes;
  }

  /** A state saved by stateToBytes() (or any reader's e little-endian doubles), checked. */
  stateFromBytes(binary) {
    const bytes = asBytes(binary);
    if (bytes.byteLength !== 8 * this.numEdges) {
      throw new RangeError(`a saved damage state of this file has ${8 * this.numEdges} bytes, got ${bytes.byteLength}`);
    }
    const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
    const state = new Float64Array(this.numEdges);
    for (let e = 0; e < state.length; e++) state[e] = view.getFloat64(8 * e, true);
    this.checkState(state);
    return state;
  }

  /** The crack segments of bond e as a Float64Array of 6 numbers per segment (empty without crack arrays). */
  crackSegmentsOf(bond) {
    if (!this.crackPtr) return new Float64Array(0);
    return this.crackSegments.subarray(6 * this.crackPtr[bond], 6 * this.crackPtr[bond + 1]);
  }

  // Sections 4, 11 and 12.4 in one pass: the inputs are checked before `state` (null: stateless) changes.
  _respond(state, point, impulse, threshold, options) {
    const [x, y, z] = vector3(point, 'point');
    const n = vector3(impulse, 'impulse');
    const T = threshold === undefined || threshold === null ? this.defaultThreshold : threshold;
    if (typeof T !== 'number' || Number.isNaN(T) || T < 0) {
      throw new RangeError(`threshold must be a number >= 0 (Infinity allowed), got ${JSON.stringify(threshold)}`);
    }
    const { numEdges: e, dim: d, edges } = this;
    const site = this._nearest(x, y, z);
    const m = Math.max(Math.abs(n[0]), Math.abs(n[1]), Math.abs(n[2]));
    const keep = options.displacement !== false;
    if (m === 0) {  // a zero impulse breaks and cracks nothing
      const none = new Uint8Array(e);
      return { site, alpha: new Float64Array(this.numModes), displacement: keep ? new Float64Array(this.numFragments * d) : null,
        jumps: keep && this.criterion === 'modes' ? new Float64Array(e * d) : null,
        ...(this.criterion === 'stress' ? { loads: new Float64Array(e) } : {}), ...this._answer(state, none, none) };
    }
    const nUnit = [n[0] / m, n[1] / m, n[2] / m];
    const alpha = this._alpha(site, nUnit);
    const limit = T / m;  // +Infinity: nothing breaks; 0 (underflow or T = 0): any nonzero measure breaks
    if (state === null && !keep && this.hasJumpTable) {  // no damage to apply: the table's groups are the answer
      const length = Math.sqrt(nUnit[0] * nUnit[0] + nUnit[1] * nUnit[1] + nUnit[2] * nUnit[2]);
      for (let i = 0; i < alpha.length; i++) alpha[i] *= m;
      const { broken, groups, numGroups } = this._tableGroups(site, length, limit);
      return { site, alpha, displacement: null, jumps: null, broken, cracked: new Uint8Array(e), groups, numGroups,
        anchored: this._anchoredOf(groups) };
    }
    // Each bond's measure a and limit b (section 12.4 step 2).
    const measure = new Float64Array(e);
    const bound = new Float64Array(e);
    let disp = null;
    let jumps = null;
    let loads = null;
    if (this.criterion === 'stress') {
      loads = this._stressMeasures(site, nUnit, limit, measure, bound, state);
      if (keep) disp = this._displacement(alpha);
    } else {
      disp = this._displacement(alpha);
      jumps = new Float64Array(e * d);
      for (let r = 0; r < e; r++) {
        const P = edges[2 * r] * d;
        const Q = edges[2 * r + 1] * d;
        if (d === 1) {
          const jump = disp[P] - disp[Q];
          jumps[r] = jump;
          measure[r] = Math.abs(jump);
        } else {
          const j0 = disp[P] - disp[Q];
          const j1 = disp[P + 1] - disp[Q + 1];
          const j2 = disp[P + 2] - disp[Q + 2];
          jumps[3 * r] = j0;
          jumps[3 * r + 1] = j1;
          jumps[3 * r + 2] = j2;
          measure[r] = Math.sqrt(j0 * j0 + j1 * j1 + j2 * j2);
        }
        bound[r] = limit;
      }
    }
    // Step 3, per bond in the spec's order: the stateless decision, the crack test (one product), the health.
    const nowBroken = new Uint8Array(e);
    const nowCracked = new Uint8Array(e);
    const c = this.crackLevel;
    const q = this.damageFactor;
    for (let b = 0; b < e; b++) {
      const a = measure[b];
      const limitB = bound[b];
      nowBroken[b] = a > limitB ? 1 : 0;
      if (state === null) continue;  // stateless without "damage": nothing cracks
      nowCracked[b] = a > c * limitB ? 1 : 0;
      let h = state[b];
      if (h > 0) {
        if (nowBroken[b]) h = 0;
        else if (nowCracked[b]) h = h - q * (a / limitB - c);  // a / b: one division, finite here
        if (h < 0) h = 0;
        state[b] = h;
      }
    }
    for (let i = 0; i < alpha.length; i++) alpha[i] *= m;
    if (disp) for (let i = 0; i < disp.length; i++) disp[i] *= m;
    if (jumps) for (let i = 0; i < jumps.length; i++) jumps[i] *= m;
    return { site, alpha, displacement: keep ? disp : null, jumps: keep ? jumps : null,
      ...(loads ? { loads } : {}), ...this._answer(state, nowBroken, nowCracked) };
  }

  // Criterion "stress" (docs/FORMAT.md section 11): the measure of bond e of site v's list is
  // g = (G0 n'0 + G1 n'1) + G2 n'2 (in this order) against the limit t * S[e]; every other bond has
  // measure 0; with feature "sharing", then section 11.1's passes (state: the damage state before this
  // hit, whose broken bonds start in the set X; null: none). Fills measure and bound; returns loads:
  // a / b with the final measure a for bonds with a > 0 (b = 0: Infinity), else 0.
  _stressMeasures(site, nUnit, limit, measure, bound, state = null) {
    const { siteBondsPtr: ptr, siteBonds: bonds, siteBondGain: G, bondStrength: S, numEdges: e } = this;
    const loads = new Float64Array(e);
    for (let b = 0; b < e; b++) bound[b] = limit * S[b];
    const [n0, n1, n2] = nUnit;
    for (let j = ptr[site]; j < ptr[site + 1]; j++) {
      measure[bonds[j]] = G[3 * j] * n0 + G[3 * j + 1] * n1 + G[3 * j + 2] * n2;
    }
    if (this.sharing) this._share(site, measure, bound, state);
    for (let r = 0; r < e; r++) {
      const a = measure[r];
      const b = bound[r];
      if (a > 0) loads[r] = b > 0 ? a / b : b === 0 ? Infinity : 0;
    }
    return loads;
  }

  // The bonds of each fragment by increasing index (F of section 11.1 for every fragment f).
  _buildFragmentBonds() {
    const { numFragments: p, numEdges: e, edges } = this;
    const ptr = new Int32Array(p + 1);
    for (let m = 0; m < 2 * e; m++) ptr[edges[m] + 1]++;
    for (let j = 0; j < p; j++) ptr[j + 1] += ptr[j];
    const next = ptr.slice(0, p);
    const list = new Int32Array(2 * e);
    for (let m = 0; m < e; m++) {  // in bond order: each fragment's list ascends
      list[next[edges[2 * m]]++] = m;
      list[next[edges[2 * m + 1]]++] = m;
    }
    this.fragmentBondsPtr = ptr;
    this.fragmentBonds = list;
  }

  // Section 11.1, literally (double precision, sums in increasing bond order): the bonds F of the struck
  // fragment f = siteFragment[site] share the load of those that broke, in passes. measure holds a0 on
  // entry and the final measure a on return (only F's entries change); bound is b = t * S.
  _share(site, measure, bound, state) {
    const f = this.siteFragment[site];
    const first = this.fragmentBondsPtr[f];
    const count = this.fragmentBondsPtr[f + 1] - first;
    const F = this.fragmentBonds.subarray(first, first + count);
    const kappa = this.sharing.concentration;
    const area = this.edgeAreas;
    const a0 = new Float64Array(count);
    const out = new Uint8Array(count);  // X, over F
    const fresh = new Uint8Array(count);
    for (let i = 0; i < count; i++) {
      const e = F[i];
      a0[i] = measure[e];
      out[i] = a0[i] > bound[e] || (state !== null && state[e] <= 0) ? 1 : 0;
    }
    for (;;) {
      let L = 0;
      for (let i = 0; i < count; i++) if (out[i]) L = L + Math.max(a0[i], 0);
      let A = 0;
      for (let i = 0; i < count; i++) if (!out[i]) A = A + area[F[i]];
      if (L === 0 || A === 0) break;
      const q = (kappa * L) / A;
      let added = false;
      for (let i = 0; i < count; i++) {
        if (out[i]) continue;
        const e = F[i];
        const a = a0[i] + q * area[e];  // one product, one sum; inf * 0 = NaN holds
        measure[e] = a;
        fresh[i] = a > bound[e] ? 1 : 0;
        if (fresh[i]) added = true;
      }
      if (!added) break;
      for (let i = 0; i < count; i++) if (fresh[i]) { out[i] = 1; fresh[i] = 0; }  // after the pass
    }
  }

  // Section 12.4 step 4: broken, cracked, groups and anchored after the update (stateless: this hit's breaks).
  _answer(state, nowBroken, nowCracked) {
    let broken = nowBroken;
    let cracked = nowCracked;
    if (state !== null) {
      broken = new Uint8Array(state.length);
      cracked = new Uint8Array(state.length);
      for (let b = 0; b < state.length; b++) {
        broken[b] = state[b] <= 0 ? 1 : 0;
        cracked[b] = !broken[b] && (nowCracked[b] || state[b] < 1) ? 1 : 0;
      }
    }
    const groups = this.groups(broken);
    return { broken, cracked, groups, numGroups: countGroups(groups), anchored: this._anchoredOf(groups) };
  }

  /** Per fragment: 1 when its group holds a fragment with anchored = 1 (all 0 without feature "anchors"). */
  _anchoredOf(groups) {
    const p = this.numFragments;
    const out = new Uint8Array(p);
    if (!this.anchored) return out;
    const held = new Uint8Array(p);
    for (let j = 0; j < p; j++) if (this.anchored[j] === 1) held[groups[j]] = 1;
    for (let j = 0; j < p; j++) out[j] = held[groups[j]];
    return out;
  }
}

const KD_LEAF = 16;
const KD_STACK = 96;  // deeper than any tree of at most 2^31 sites

/** Union-find root with path halving. */
function root(parent, j) {
  while (parent[j] !== j) {
    parent[j] = parent[parent[j]];
    j = parent[j];
  }
  return j;
}

function countGroups(groups) {
  let count = 0;
  for (let j = 0; j < groups.length; j++) if (groups[j] === j) count++;
  return count;
}

// ------------------------------------------------------------------ levels (docs/FORMAT.md section 14)
//
// A body is a set of fragments (its children) with its own impact data: body 0 is this runtime (the
// p level-1 fragments), body b >= 1 breaks fragment bodyFragment[b] into fragments childPtr[b] ..
// childPtr[b+1]-1 (global indices over every level). body(b) is body b's view, a FractureRuntime of its
// own (parseRuntime checks it as a file), on which project() and hit() run in local indices. An object
// state is one Float64Array of every body's bond healths; hitPiece() hits the piece holding a shown
// fragment (section 14.5) and objectPieces() lists the rigid bodies a game shows (section 14.4).

const LEVEL_ARRAYS = [['parent', 'int32', 1], ['body_fragment', 'int32', 1], ['body_child_ptr', 'int32', 1],
  ['body_site_ptr', 'int32', 1], ['body_sites', 'float32', 2], ['body_B', 'float32', 3], ['body_W', 'float32', 3],
  ['body_edge_ptr', 'int32', 1], ['body_edges', 'int32', 2], ['body_edge_areas', 'float32', 1]];
const LEVEL_STRESS = [['body_site_bonds_ptr', 'int32', 1], ['body_site_bonds', 'int32', 1],
  ['body_site_bond_gain', 'float32', 2], ['body_bond_strength', 'float32', 1]];
// With feature "sharing" (section 11.1): the fragment each row of body_sites loads, local to its body.
const LEVEL_SHARING = [['body_site_fragment', 'int32', 1]];
const LEVEL_CRACKS = [['body_crack_ptr', 'int32', 1], ['body_crack_segments', 'float32', 3]];

function ptrOk(ptr, first, end) {
  if (ptr[0] !== first || ptr[ptr.length - 1] !== end) return false;
  for (let i = 1; i < ptr.length; i++) if (ptr[i] < ptr[i - 1]) return false;
  return true;
}

// A body's view as a header object and binary bytes (arrays 16-byte aligned), for parseRuntime.
function viewFile(header, arrays) {
  let size = 0;
  const table = {};
  for (const [name, dtype, shape] of arrays) {
    const length = 4 * shape.reduce((a, n) => a * n, 1);
    table[name] = { dtype, shape, byte_offset: size, byte_length: length };
    size += Math.ceil(length / 16) * 16;
  }
  const bytes = new Uint8Array(size);
  const out = new DataView(bytes.buffer);
  for (const [name, dtype, , values] of arrays) {
    const at = table[name].byte_offset;
    for (let i = 0; i < values.length; i++) {
      if (dtype === 'int32') out.setInt32(at + 4 * i, values[i], true);
      else out.setFloat32(at + 4 * i, values[i], true);
    }
  }
  return [{ ...header, buffer: { uri: 'view.fracture.bin', byte_length: size }, arrays: table }, bytes];
}

Object.assign(FractureRuntime.prototype, {
  _readLevels(h, view, options) {
    const c = h.counts;
    const stress = this.criterion === 'stress';
    const cracks = LEVEL_CRACKS.some(([name]) => h.arrays[name] !== undefined);
    const sharing = this.sharing !== null;
    const layout = [...LEVEL_ARRAYS, ...(stress ? LEVEL_STRESS : []), ...(sharing ? LEVEL_SHARING : []),
      ...(cracks ? LEVEL_CRACKS : [])];
    const a = {};
    for (const [name, dtype, ndim] of layout) {
      const entry = h.arrays[name];
      const shapes = { [name]: entry && Array.isArray(entry.shape) ? entry.shape : [] };
      a[name] = readArray(name, dtype, ndim, entry, view, shapes);
      a[name].shape = entry.shape;
    }
    const p = this.numFragments;
    const d = this.dim;
    const pAll = a.parent.length;
    const nb = a.body_fragment.length;
    const S = a.body_sites.shape[0];
    const K = a.body_B.shape[1];
    const E = a.body_edges.shape[0];
    const C = pAll - p;
    if (c.bodies !== nb || c.all_fragments !== pAll || c.body_sites !== S || c.body_modes !== K || c.body_edges !== E) {
      fail('header counts of the levels arrays do not match the arrays');
    }
    if (pAll <= p || nb < 2) fail('a file with levels has more fragments than level 1 and at least two bodies');
    const info = h.levels;
    if (!info || typeof info !== 'object' || Array.isArray(info)) fail("the feature 'levels' needs a header object 'levels'");
    const names = h.child_names;
    if (!Array.isArray(names) || names.length !== C || !names.every((n) => typeof n === 'string')) {
      fail(`child_names must be ${C} strings`);
    }
    const same = (name, shape) => a[name].shape.join(',') === shape.join(',');
    if (!same('body_child_ptr', [nb + 1]) || !same('body_site_ptr', [nb + 1]) || !same('body_edge_ptr', [nb + 1]) ||
        !same('body_sites', [S, 3]) || K < 1 || !same('body_B', [S, K, d]) || !same('body_W', [K, C, d]) ||
        !same('body_edges', [E, 2]) || !same('body_edge_areas', [E])) fail('levels array shapes do not agree with each other');
    const N = stress ? a.body_site_bonds.length : 0;
    if (stress && (!same('body_site_bonds_ptr', [S + 1]) || !same('body_site_bond_gain', [N, 3]) ||
        !same('body_bond_strength', [E]) || c.body_site_bonds !== N)) fail('levels stress arrays do not agree');
    if (sharing && !same('body_site_fragment', [S])) fail(`body_site_fragment must have ${S} entries`);
    const n = cracks ? a.body_crack_segments.shape[0] : 0;
    if (cracks && (!same('body_crack_ptr', [E + 1]) || !same('body_crack_segments', [n, 2, 3]) ||
        c.body_crack_segments !== n)) fail('levels crack arrays do not agree');
    const { parent, body_fragment: owner, body_child_ptr: child, body_site_ptr: sitePtr, body_edge_ptr: edgePtr } = a;
    const level = new Int32Array(pAll);
    let deepest = 1;
    for (let g = 0; g < pAll; g++) {
      if (g < p ? parent[g] !== -1 : !(parent[g] >= 0 && parent[g] < g)) {
        fail('parent must be -1 for the level-1 fragments and a smaller fragment index for every other');
      }
      level[g] = parent[g] < 0 ? 1 : level[parent[g]] + 1;
      deepest = Math.max(deepest, level[g]);
    }
    let ok = owner[0] === -1 && owner[1] >= 0 && owner[nb - 1] < pAll;
    for (let b = 2; ok && b < nb; b++) ok = owner[b] > owner[b - 1];
    if (!ok) fail('body_fragment must be -1 for body 0, then fragment indices strictly increasing');
    if (!ptrOk(child, 0, pAll) || child[1] !== p) fail(`body_child_ptr must start at 0, then ${p}, and end at ${pAll}`);
    for (let b = 0; b < nb; b++) if (child[b + 1] - child[b] < 2) fail(`every body must have at least 2 children (body ${b})`);
    for (let b = 1; b < nb; b++) {
      for (let g = child[b]; g < child[b + 1]; g++) {
        if (parent[g] !== owner[b]) fail('parent of every child must be the fragment of the body that holds it');
      }
    }
    if (!ptrOk(sitePtr, 0, S) || !ptrOk(edgePtr, 0, E) || sitePtr[1] !== 0 || edgePtr[1] !== 0) {
      fail('body_site_ptr and body_edge_ptr must start at 0 (body 0 has no rows) and end at their arrays\' lengths');
    }
    for (let b = 1; b < nb; b++) if (sitePtr[b + 1] <= sitePtr[b]) fail(`body ${b} has no sites`);
    if (stress && !ptrOk(a.body_site_bonds_ptr, 0, N)) fail('body_site_bonds_ptr must start at 0, never decrease and end at N');
    if (cracks && !ptrOk(a.body_crack_ptr, 0, n)) fail('body_crack_ptr must start at 0, never decrease and end at n');
    for (let b = 1; b < nb; b++) {
      if (this.anchored && owner[b] < p && this.anchored[owner[b]] === 1) fail('an anchored fragment cannot be broken further');
    }
    if (!Number.isInteger(info.count) || info.count !== deepest) fail(`levels.count must be the deepest level, ${deepest}`);
    const thresholds = info.thresholds;
    if (!Array.isArray(thresholds) || thresholds.length !== deepest ||
        !thresholds.every((t) => typeof t === 'number' && Number.isFinite(t) && t >= 0)) {
      fail(`levels.thresholds must list ${deepest} finite numbers >= 0, one per level`);
    }
    if (thresholds[0] !== this.defaultThreshold) fail('levels.thresholds[0] must be default_threshold');
    const radii = Array.isArray(info.impact_radii) ? info.impact_radii : [];
    this.levels = { count: deepest, parent, level, bodyFragment: owner, childPtr: child, numAllFragments: pAll,
      bodyOf: new Int32Array(pAll).fill(-1), holding: new Int32Array(pAll), stateOffsets: new Int32Array(nb + 1),
      views: [this], childNames: names.slice() };
    const lv = this.levels;
    for (let b = 1; b < nb; b++) {
      lv.bodyOf[owner[b]] = b;
      for (let g = child[b]; g < child[b + 1]; g++) lv.holding[g] = b;
      lv.stateOffsets[b] = this.numEdges + edgePtr[b];
    }
    lv.stateOffsets[nb] = this.numEdges + E;
    const features = [...(this.damage ? ['damage'] : []), ...(sharing ? ['sharing'] : []), ...(stress ? ['stress'] : [])];
    for (let b = 1; b < nb; b++) {
      const [s0, s1, g0, g1, e0, e1] = [sitePtr[b], sitePtr[b + 1], child[b] - p, child[b + 1] - p, edgePtr[b], edgePtr[b + 1]];
      const [sb, cb, eb] = [s1 - s0, g1 - g0, e1 - e0];
      const bodyLevel = level[owner[b]] + 1;
      const W = new Float64Array(K * cb * d);
      for (let k = 0; k < K; k++) W.set(a.body_W.subarray((k * C + g0) * d, (k * C + g1) * d), k * cb * d);
      const arrays = [['sites', 'float32', [sb, 3], a.body_sites.subarray(3 * s0, 3 * s1)],
        ['B', 'float32', [sb, K, d], a.body_B.subarray(s0 * K * d, s1 * K * d)], ['W', 'float32', [K, cb, d], W],
        ['edges', 'int32', [eb, 2], a.body_edges.subarray(2 * e0, 2 * e1)],
        ['edge_areas', 'float32', [eb], a.body_edge_areas.subarray(e0, e1)]];
      const counts = { sites: sb, modes: K, fragments: cb, edges: eb };
      if (stress) {
        const ptr = a.body_site_bonds_ptr.subarray(s0, s1 + 1);
        const [n0, n1] = [ptr[0], ptr[ptr.length - 1]];
        counts.site_bonds = n1 - n0;
        arrays.push(['site_bonds_ptr', 'int32', [sb + 1], ptr.map((x) => x - n0)],
          ['site_bonds', 'int32', [n1 - n0], a.body_site_bonds.subarray(n0, n1)],
          ['site_bond_gain', 'float32', [n1 - n0, 3], a.body_site_bond_gain.subarray(3 * n0, 3 * n1)],
          ['bond_strength', 'float32', [eb], a.body_bond_strength.subarray(e0, e1)]);
        // Values within the body's children: checked when parseRuntime reads the view.
        if (sharing) arrays.push(['site_fragment', 'int32', [sb], a.body_site_fragment.subarray(s0, s1)]);
      }
      if (cracks) {
        const ptr = a.body_crack_ptr.subarray(e0, e1 + 1);
        const [c0, c1] = [ptr[0], ptr[ptr.length - 1]];
        counts.crack_segments = c1 - c0;
        arrays.push(['crack_ptr', 'int32', [eb + 1], ptr.map((x) => x - c0)],
          ['crack_segments', 'float32', [c1 - c0, 2, 3], a.body_crack_segments.subarray(6 * c0, 6 * c1)]);
      }
      const [viewHeader, bytes] = viewFile({ format: FORMAT_NAME, version: 2, features, criterion: this.criterion,
        dim: d, counts, fragment_names: names.slice(g0, g1), transform: this.transform,
        default_threshold: thresholds[bodyLevel - 1],
        impact_radius: Number.isFinite(radii[bodyLevel - 1]) ? radii[bodyLevel - 1] : this.impactRadius,
        damage: h.damage, ...(sharing ? { sharing: h.sharing } : {}) }, arrays);
      try {
        lv.views.push(parseRuntime(viewHeader, bytes, { checkCrc: false, jumpTable: options.jumpTable, [VIEW]: true }));
      } catch (err) {
        fail(`body ${b}: ${err.message}`);
      }
    }
  },

  /** Body b's view (body 0: this runtime). */
  body(b) { return this.levels ? this.levels.views[b] : b === 0 ? this : undefined; },
  /** The first child (global) of body b; b = numBodies gives p_all. */
  bodyFirst(b) { return this.levels ? this.levels.childPtr[b] : b === 0 ? 0 : this.numFragments; },
  /** The body breaking fragment g into its children, -1 for a leaf. */
  bodyOf(g) { return this.levels ? this.levels.bodyOf[g] : -1; },
  /** The body whose child fragment g is (0 at level 1). */
  bodyHolding(g) { return this.levels ? this.levels.holding[g] : 0; },
  /** Fragment g's parent, -1 at level 1. */
  parentOf(g) { return this.levels ? this.levels.parent[g] : -1; },
  /** The GLB node name of fragment g (any level). */
  anyFragmentName(g) { return g < this.numFragments ? this.fragmentNames[g] : this.levels.childNames[g - this.numFragments]; },
  _stateOffset(b) { return this.levels ? this.levels.stateOffsets[b] : b === 0 ? 0 : this.numEdges; },
  _bodyHealth(state, b) { return state.subarray(this._stateOffset(b), this._stateOffset(b + 1)); },

  /** A fresh object state (section 14.4): every body's bond healths, all 1. */
  newObjectState() { return new Float64Array(this._stateOffset(this.numBodies)).fill(1); },

  /** Throw unless state is an object state of this file: a Float64Array of e + E healths in [0, 1]. */
  checkObjectState(state) {
    const size = this._stateOffset(this.numBodies);
    if (!(state instanceof Float64Array) || state.length !== size) {
      throw new TypeError(`an object state must be a Float64Array of ${size} bond healths (every body's)`);
    }
    for (let i = 0; i < size; i++) if (!(state[i] >= 0 && state[i] <= 1)) throw new RangeError(`an object state holds healths in [0, 1]; entry ${i} has ${state[i]}`);
  },

  // Groups (smallest local index) of body b's children over bonds with health > 0 between two kept children.
  _bodyGroups(state, b, keep = null) {
    const view = this.body(b);
    const health = this._bodyHealth(state, b);
    const parent = new Int32Array(view.numFragments).map((_, j) => j);
    for (let m = 0; m < view.numEdges; m++) {
      const [P, Q] = [view.edges[2 * m], view.edges[2 * m + 1]];
      if (health[m] > 0 && (keep === null || (keep[P] && keep[Q]))) {
        const [x, y] = [root(parent, P), root(parent, Q)];
        if (x !== y) parent[Math.max(x, y)] = Math.min(x, y);
      }
    }
    for (let j = 0; j < parent.length; j++) parent[j] = root(parent, j);
    return parent;
  },

  /** Whether fragment g broke into its children (its body's unbroken bonds leave two or more groups). */
  isSplit(state, g) {
    const b = this.bodyOf(g);
    return b >= 0 && countGroups(this._bodyGroups(state, b)) >= 2;
  },

  /** Whether fragment g is shown: not split, every ancestor split. */
  isShown(state, g) {
    if (!(Number.isInteger(g) && g >= 0 && g < this.numAllFragments) || this.isSplit(state, g)) return false;
    for (let a = this.parentOf(g); a >= 0; a = this.parentOf(a)) if (!this.isSplit(state, a)) return false;
    return true;
  },

  // The pieces of body b's kept children: { body, fragments (global, ascending), anchored }.
  _piecesOf(state, b, keep) {
    const groups = this._bodyGroups(state, b, keep);
    const first = this.bodyFirst(b);
    const byRoot = new Map();
    for (let j = 0; j < groups.length; j++) {
      if (!keep[j]) continue;
      if (!byRoot.has(groups[j])) byRoot.set(groups[j], { body: b, fragments: [], anchored: false });
      const piece = byRoot.get(groups[j]);
      piece.fragments.push(first + j);
      if (b === 0 && this.anchored && this.anchored[j] === 1) piece.anchored = true;
    }
    return [...byRoot.values()];  // insertion order: by smallest member
  },

  /** Every piece of the object (section 14.4): body by body, each by its first fragment. */
  objectPieces(state) {
    this.checkObjectState(state);
    const out = [];
    for (let b = 0; b < this.numBodies; b++) {
      const first = this.bodyFirst(b);
      const count = this.body(b).numFragments;
      if (b > 0 && !(this.isSplit(state, this.levels.bodyFragment[b]) && this._opened(state, this.levels.bodyFragment[b]))) continue;
      const keep = new Uint8Array(count).map((_, j) => (this.isSplit(state, first + j) ? 0 : 1));
      out.push(...this._piecesOf(state, b, keep));
    }
    return out;
  },

  // Whether every ancestor of g is split.
  _opened(state, g) {
    for (let a = this.parentOf(g); a >= 0; a = this.parentOf(a)) if (!this.isSplit(state, a)) return false;
    return true;
  },

  /**
   * Hit the piece holding the shown fragment `struck` (docs/FORMAT.md section 14.5); `state` (an object
   * state) is updated in place, and left as it was when the hit is refused (invalid inputs, state, or a
   * fragment that is not shown). Point and impulse in the asset's model space; threshold undefined: each
   * body's default. Returns { body, result (body's answer over all its children, local indices),
   * childBody (-1: none), childResult, split, pieces (what struck's piece became) }.
   */
  hitPiece(state, struck, point, impulse, threshold) {
    this.checkObjectState(state);
    if (!this.isShown(state, struck)) throw new RangeError(`fragment ${struck} is not shown (split, or inside an unbroken parent)`);
    const b = this.bodyHolding(struck);
    const view = this.body(b);
    const first = this.bodyFirst(b);
    const keep = new Uint8Array(view.numFragments).map((_, j) => (this.isSplit(state, first + j) ? 0 : 1));
    const before = this._bodyGroups(state, b, keep);
    const inside = keep.map((k, j) => (k && before[j] === before[struck - first] ? 1 : 0));
    const health = this._bodyHealth(state, b);
    const trial = Float64Array.from(health);
    const hit = view.hit(trial, point, impulse, threshold);  // checks the inputs before anything changes
    const broken = new Uint8Array(view.numEdges);
    const cracked = new Uint8Array(view.numEdges);
    for (let m = 0; m < view.numEdges; m++) {
      const within = inside[view.edges[2 * m]] && inside[view.edges[2 * m + 1]];
      if (within) health[m] = trial[m];
      broken[m] = health[m] <= 0 ? 1 : 0;
      cracked[m] = !broken[m] && ((hit.cracked[m] && within) || health[m] < 1) ? 1 : 0;
    }
    const groups = this._bodyGroups(state, b);
    const result = { ...hit, groups, numGroups: countGroups(groups), broken, cracked, anchored: view._anchoredOf(groups) };
    const childBody = this.bodyOf(struck);
    let childResult = null;
    let split = false;
    if (childBody >= 0) {
      childResult = this.body(childBody).hit(this._bodyHealth(state, childBody), point, impulse, threshold);
      split = childResult.numGroups >= 2;
    }
    if (split) inside[struck - first] = 0;
    const pieces = this._piecesOf(state, b, inside);
    if (split) {
      const cfirst = this.bodyFirst(childBody);
      const ckeep = new Uint8Array(this.body(childBody).numFragments).map((_, j) => (this.isSplit(state, cfirst + j) ? 0 : 1));
      pieces.push(...this._piecesOf(state, childBody, ckeep));
    }
    return { struck, body: b, result, childBody, childResult, split, pieces };
  },
});

// Getters (Object.assign would copy their values): bodies in the file (1 without levels), and fragments of
// every level (p_all; p without levels).
Object.defineProperties(FractureRuntime.prototype, {
  numBodies: { get() { return this.levels ? this.levels.views.length : 1; } },
  numAllFragments: { get() { return this.levels ? this.levels.numAllFragments : this.numFragments; } },
});
