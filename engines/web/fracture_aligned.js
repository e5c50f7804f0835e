// fracture_aligned.js - aligned fracture at runtime (ES module, no dependencies).
//
// Reads the companion file `<stem>.aligned.json` + `<stem>.aligned.bin` that `fracture bake`
// writes with `--set aligned.enabled=true` (docs/FORMAT.md section 13 of the fracture repository)
// and cuts the asset where it is hit: a fracture pattern (Voronoi cells, finer near its centre) is
// placed at the hit point, oriented by the impulse, and intersected with the asset's convex pieces.
// Pieces inside one cell stay whole; the others are clipped by the cells they meet; the parts in one
// cell form a new fragment with its triangles cut along the cells (interior material on new faces).
// Same arithmetic, in the same order, as the Python reference and the C reader: the same numbers.
//
//   import { loadAligned, alignedFracture } from './fracture_aligned.js';
//   const data = loadAligned(await (await fetch('chair.aligned.json')).text(),
//                            await (await fetch('chair.aligned.bin')).arrayBuffer());
//   const { fragments } = alignedFracture(data, point, impulse, data.defaultScale);
//
// MIT licence, Copyright (c) fracture developers (see LICENSE next to this file).

export const ALIGNED_FORMAT = 'fracture-aligned';
export const ALIGNED_VERSION = 1;
const EPS_RELATIVE = 1e-9;
const KEEP_RELATIVE = 1e-9;
const UV_AXIS_TIE = 1e-9;

export class AlignedError extends Error {
  constructor(message) {
    super(message);
    this.name = 'AlignedError';
  }
}

const LAYOUT = [
  ['settings', 'float32', []], ['piece_fragment', 'int32', []], ['piece_sphere', 'float32', [4]],
  ['piece_vertex_offsets', 'int32', []], ['piece_vertices', 'float32', [3]], ['piece_face_offsets', 'int32', []],
  ['face_planes', 'float32', [4]], ['face_loop_offsets', 'int32', []], ['face_loops', 'int32', []],
  ['piece_triangle_offsets', 'int32', []], ['triangle_positions', 'float32', [3, 3]],
  ['triangle_normals', 'float32', [3, 3]], ['triangle_uvs', 'float32', [3, 2]], ['triangle_materials', 'int32', []],
  ['pattern_site_offsets', 'int32', []], ['pattern_sites', 'float32', [3]], ['cell_neighbor_offsets', 'int32', []],
  ['cell_neighbors', 'int32', []], ['cell_planes', 'float32', [4]], ['boundary_planes', 'float32', [4]],
  ['cell_boundary_offsets', 'int32', []], ['cell_boundary', 'int32', []],
];

let crcTable = null;
function crc32(bytes) {
  if (!crcTable) {
    crcTable = new Uint32Array(256);
    for (let i = 0; i < 256; i++) {
      let c = i;
      for (let k = 0; k < 8; k++) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
      crcTable[i] = c >>> 0;
    }
  }
  let crc = 0xffffffff;
  for (let i = 0; i < bytes.length; i++) crc = crcTable[(crc ^ bytes[i]) & 0xff] ^ (crc >>> 8);
  return (crc ^ 0xffffffff) >>> 0;
}

const isCount = (x) => Number.isInteger(x) && x >= 0;

function checkOffsets(name, off, count, end) {
  if (off.length !== count + 1 || off[0] !== 0 || off[count] !== end) {
    throw new AlignedError(`${name} must have ${count + 1} entries, start at 0 and end at ${end}`);
  }
  for (let i = 0; i < count; i++) if (off[i + 1] < off[i]) throw new AlignedError(`${name} decreases`);
}

/**
 * Parse and validate an aligned-fracture file.
 * @param {string|ArrayBuffer|Uint8Array|object} header the `.aligned.json` text (or its parsed object)
 * @param {ArrayBuffer|Uint8Array} binary the `.aligned.bin` bytes
 * @param {{checkCrc?: boolean}} [options]
 * @returns {object} the data: typed arrays by name, `materials`, `interiorMaterial`, `uvScale`,
 *   `defaultScale`, `pieces`, `patterns`, and the per-piece volumes and centroids
 */
export function loadAligned(header, binary, { checkCrc = true } = {}) {
  let h = header;
  if (typeof h !== 'object' || h instanceof ArrayBuffer || ArrayBuffer.isView(h)) {
    const text = typeof h === 'string' ? h : new TextDecoder('utf-8', { fatal: true }).decode(h);
    try {
      h = JSON.parse(text);
    } catch (e) {
      throw new AlignedError(`not a JSON aligned-fracture file (${e.message})`);
    }
  }
  if (!h || h.format !== ALIGNED_FORMAT) throw new AlignedError(`not an aligned-fracture file (format "${ALIGNED_FORMAT}")`);
  if (h.version !== ALIGNED_VERSION) throw new AlignedError(`aligned-fracture version ${h.version} is not supported (this reader knows 1)`);
  const bytes = binary instanceof Uint8Array ? binary : new Uint8Array(binary);
  const buffer = h.buffer, table = h.arrays;
  if (!buffer || !table || typeof table !== 'object' || !Array.isArray(h.materials) || !isCount(h.interior_material)
      || !isCount(buffer.byte_length)) {
    throw new AlignedError('the header misses buffer, arrays, materials or interior_material');
  }
  if (buffer.byte_length !== bytes.length) throw new AlignedError('the binary file\'s size differs from buffer.byte_length');
  if (checkCrc && buffer.crc32 !== undefined && crc32(bytes) !== buffer.crc32) {
    throw new AlignedError('the binary file does not match its header (crc32)');
  }
  const arrays = {};
  for (const [name, dtype, trailing] of LAYOUT) {
    const e = table[name];
    if (!e || e.dtype !== dtype || !Array.isArray(e.shape) || !isCount(e.byte_offset) || !isCount(e.byte_length)) {
      throw new AlignedError(`array '${name}' is missing or malformed`);
    }
    if (e.shape.length !== trailing.length + 1 || !e.shape.every(isCount) || trailing.some((t, i) => e.shape[i + 1] !== t)) {
      throw new AlignedError(`array '${name}' has the wrong shape`);
    }
    const count = e.shape.reduce((a, b) => a * b, 1);
    if (e.byte_length !== 4 * count || e.byte_offset % 16 !== 0 || e.byte_offset + e.byte_length > bytes.length) {
      throw new AlignedError(`array '${name}' does not fit the binary file`);
    }
    // a copy (aligned; little-endian hosts): Uint8Array.prototype.slice, also for a Node Buffer (whose slice is a view)
    const copy = Uint8Array.prototype.slice.call(bytes, e.byte_offset, e.byte_offset + e.byte_length).buffer;
    arrays[name] = dtype === 'float32' ? new Float32Array(copy) : new Int32Array(copy);
    arrays[name].rows = e.shape[0];
  }
  const a = arrays;
  for (const [name, dtype] of LAYOUT) {
    if (dtype === 'float32' && !a[name].every(Number.isFinite)) throw new AlignedError(`array '${name}' has a value that is not finite`);
  }
  const P = a.piece_fragment.length, Q = a.pattern_site_offsets.length - 1;
  const V = a.piece_vertices.rows, F = a.face_planes.rows, L = a.face_loops.length, T = a.triangle_materials.length;
  const S = a.pattern_sites.rows, N = a.cell_neighbors.length, M = h.materials.length;
  if (P < 1 || Q < 1) throw new AlignedError('the file needs at least one piece and one pattern');
  if (a.settings.length !== 2 || !(a.settings[0] > 0) || !(a.settings[1] > 0)) throw new AlignedError('settings must hold 2 values > 0');
  if (a.piece_sphere.rows !== P || a.cell_planes.rows !== N || a.triangle_positions.rows !== T
      || a.triangle_normals.rows !== T || a.triangle_uvs.rows !== T) throw new AlignedError('array lengths do not agree');
  checkOffsets('piece_vertex_offsets', a.piece_vertex_offsets, P, V);
  checkOffsets('piece_face_offsets', a.piece_face_offsets, P, F);
  checkOffsets('face_loop_offsets', a.face_loop_offsets, F, L);
  checkOffsets('piece_triangle_offsets', a.piece_triangle_offsets, P, T);
  checkOffsets('pattern_site_offsets', a.pattern_site_offsets, Q, S);
  checkOffsets('cell_neighbor_offsets', a.cell_neighbor_offsets, S, N);
  if (M < 1 || h.interior_material >= M || !h.materials.every((m) => typeof m === 'string')) {
    throw new AlignedError('interior_material must index materials');
  }
  for (let t = 0; t < T; t++) if (a.triangle_materials[t] < 0 || a.triangle_materials[t] >= M) throw new AlignedError('a triangle\'s material is out of range');
  const pv = a.piece_vertex_offsets, pf = a.piece_face_offsets, fl = a.face_loop_offsets;
  let maxFaces = 0, maxVertices = 0, maxDegree = 0, maxSites = 0;
  for (let k = 0; k < P; k++) {
    const nv = pv[k + 1] - pv[k], nf = pf[k + 1] - pf[k];
    if (a.piece_fragment[k] < 0 || !(a.piece_sphere[4 * k + 3] > 0)) throw new AlignedError('piece_fragment < 0 or a sphere radius not > 0');
    if (nv < 4 || nv > 255 || nf < 4) throw new AlignedError('a piece needs 4 to 255 vertices and at least 4 faces');
    maxFaces = Math.max(maxFaces, nf);
    maxVertices = Math.max(maxVertices, nv);
    for (let f = pf[k]; f < pf[k + 1]; f++) {
      if (fl[f + 1] - fl[f] < 3 || fl[f + 1] - fl[f] > 1024) throw new AlignedError('a face loop has fewer than 3 corners');
      for (let i = fl[f]; i < fl[f + 1]; i++) if (a.face_loops[i] < 0 || a.face_loops[i] >= nv) throw new AlignedError('a face loop\'s corner is out of range');
    }
  }
  const ps = a.pattern_site_offsets, cn = a.cell_neighbor_offsets, sites = a.pattern_sites;
  for (let q = 0; q < Q; q++) {
    const lo = ps[q], hi = ps[q + 1];
    if (hi - lo < 1) throw new AlignedError('a pattern has no sites');
    maxSites = Math.max(maxSites, hi - lo);
    for (let i = lo; i < hi; i++) {
      maxDegree = Math.max(maxDegree, cn[i + 1] - cn[i]);
      for (let e = cn[i]; e < cn[i + 1]; e++) {
        const j = a.cell_neighbors[e];
        if (j < 0 || j >= hi - lo || j === i - lo) throw new AlignedError('a cell\'s neighbour is out of range');
      }
      for (let j = lo; j < i; j++) {
        if (sites[3 * i] === sites[3 * j] && sites[3 * i + 1] === sites[3 * j + 1] && sites[3 * i + 2] === sites[3 * j + 2]) {
          throw new AlignedError('a pattern has two equal sites');
        }
      }
    }
  }
  const B = a.boundary_planes.rows, bp = a.boundary_planes;
  if (B !== 0 && B < 4) throw new AlignedError('boundary_planes must be none or at least 4');
  checkOffsets('cell_boundary_offsets', a.cell_boundary_offsets, S, a.cell_boundary.length);
  if (!a.cell_boundary.every((b) => b >= 0 && b < B)) throw new AlignedError('a cell\'s boundary plane is out of range');
  for (let b = 0; b < B; b++) {
    if (Math.abs(Math.sqrt((bp[4 * b] * bp[4 * b] + bp[4 * b + 1] * bp[4 * b + 1]) + bp[4 * b + 2] * bp[4 * b + 2]) - 1) > 1e-5) {
      throw new AlignedError('a boundary plane\'s normal is not of unit length');
    }
    for (let i = 0; i < S; i++) {
      if (!(dot3(bp, 4 * b, sites, 3 * i) < bp[4 * b + 3])) throw new AlignedError('a site lies outside the boundary');
    }
  }
  const data = {
    arrays, materials: h.materials.slice(), interiorMaterial: h.interior_material, pieces: P, patterns: Q,
    triangles: T, uvScale: a.settings[0], defaultScale: a.settings[1], patternInfo: h.patterns || [],
  };
  data.work = makeWork(maxFaces, maxVertices, maxDegree, maxSites);
  data.pieceMass = new Float64Array(4 * P);
  for (let k = 0; k < P; k++) {
    const poly = data.work.buf[0];
    piecePoly(data, k, poly);
    polyMass(poly, data.pieceMass, 4 * k);
  }
  return data;
}

/** Sites in pattern `pattern` (cells). */
export function patternSites(data, pattern) {
  const ps = data.arrays.pattern_site_offsets;
  return pattern >= 0 && pattern < data.patterns ? ps[pattern + 1] - ps[pattern] : 0;
}

/** A stored piece: its corners, faces and the range of its triangles (what a whole part shows). */
export function getPiece(data, k) {
  const a = data.arrays, pv = a.piece_vertex_offsets, pf = a.piece_face_offsets, fl = a.face_loop_offsets;
  const loops = [];
  for (let f = pf[k]; f < pf[k + 1]; f++) loops.push(a.face_loops.subarray(fl[f], fl[f + 1]));
  return {
    fragment: a.piece_fragment[k], vertices: a.piece_vertices.subarray(3 * pv[k], 3 * pv[k + 1]),
    planes: a.face_planes.subarray(4 * pf[k], 4 * pf[k + 1]), loops,
    triangleFirst: a.piece_triangle_offsets[k], triangleCount: a.piece_triangle_offsets[k + 1] - a.piece_triangle_offsets[k],
    volume: data.pieceMass[4 * k], centroid: Array.from(data.pieceMass.subarray(4 * k + 1, 4 * k + 4)),
  };
}

// ------------------------------------------------------------------------------------ geometry

const dot3 = (a, i, b, j) => (a[i] * b[j] + a[i + 1] * b[j + 1]) + a[i + 2] * b[j + 2];

function smallestAxis(n, o) {
  let axis = 0;
  if (Math.abs(n[o + 1]) < Math.abs(n[o + axis])) axis = 1;
  if (Math.abs(n[o + 2]) < Math.abs(n[o + axis])) axis = 2;
  return axis;
}

// Unit axes a, b with a x b = n (n at n[o..o+2]); written into out[0..5].
function planeBasis(n, o, out) {
  const axis = smallestAxis(n, o), k = n[o + axis];
  const t = [-(k * n[o]), -(k * n[o + 1]), -(k * n[o + 2])];
  t[axis] = 1.0 - k * n[o + axis];
  const length = Math.sqrt((t[0] * t[0] + t[1] * t[1]) + t[2] * t[2]);
  const a0 = t[0] / length, a1 = t[1] / length, a2 = t[2] / length;
  out[0] = a0; out[1] = a1; out[2] = a2;
  out[3] = n[o + 1] * a2 - n[o + 2] * a1;
  out[4] = n[o + 2] * a0 - n[o] * a2;
  out[5] = n[o] * a1 - n[o + 1] * a0;
}

function boxUv(x, xo, n, no, uvScale, out, oo) {
  const ax = Math.abs(n[no]), ay = Math.abs(n[no + 1]), az = Math.abs(n[no + 2]);
  let mx = ax > ay ? ax : ay;
  if (az > mx) mx = az;
  const axis = ax >= mx - UV_AXIS_TIE ? 0 : (ay >= mx - UV_AXIS_TIE ? 1 : 2);
  const sign = n[no + axis] < 0 ? -1.0 : 1.0;
  const u = x[xo + [1, 0, 0][axis]] * sign * (axis === 1 ? -1.0 : 1.0);
  out[oo] = u / uvScale;
  out[oo + 1] = x[xo + [2, 2, 1][axis]] / uvScale;
}

function makePoly(vcap, fcap, lcap) {
  return { nv: 0, nf: 0, nl: 0, v: new Float64Array(3 * vcap), plane: new Float64Array(4 * fcap),
    isnew: new Int32Array(fcap), loopOff: new Int32Array(fcap + 1), loops: new Int32Array(lcap) };
}

function makeWork(maxFaces, maxVertices, maxDegree, maxSites) {
  const fcap = maxFaces + maxDegree + 8, vcap = 2 * fcap + maxVertices + 64, lcap = 2 * (vcap + fcap) + 64;
  const ccap = Math.max(1024, maxSites + 64, vcap);
  return {
    vcap, fcap, lcap, ccap, buf: [makePoly(vcap, fcap, lcap), makePoly(vcap, fcap, lcap), makePoly(vcap, fcap, lcap)],
    dist: new Float64Array(vcap), side: new Int32Array(vcap), renumber: new Int32Array(vcap), used: new Uint8Array(vcap),
    points: new Int32Array(vcap), cross: new Int32Array(3 * lcap), keys: new Float64Array(3 * (vcap + 1)),
    corners: [new Float64Array(8 * ccap), new Float64Array(8 * ccap)], cdist: new Float64Array(ccap),
    cside: new Int32Array(ccap), basis: new Float64Array(6), tri: new Float64Array(24),
  };
}

function piecePoly(data, k, p) {
  const a = data.arrays, pv = a.piece_vertex_offsets, pf = a.piece_face_offsets, fl = a.face_loop_offsets;
  p.nv = pv[k + 1] - pv[k];
  p.nf = pf[k + 1] - pf[k];
  for (let i = 0; i < 3 * p.nv; i++) p.v[i] = a.piece_vertices[3 * pv[k] + i];
  p.nl = 0;
  p.loopOff[0] = 0;
  for (let f = 0; f < p.nf; f++) {
    for (let c = 0; c < 4; c++) p.plane[4 * f + c] = a.face_planes[4 * (pf[k] + f) + c];
    p.isnew[f] = 0;
    for (let i = fl[pf[k] + f]; i < fl[pf[k] + f + 1]; i++) p.loops[p.nl++] = a.face_loops[i];
    p.loopOff[f + 1] = p.nl;
  }
}

function polyMass(p, out, o) {
  const v = p.v, ox = v[0], oy = v[1], oz = v[2];
  let six = 0, sx = 0, sy = 0, sz = 0;
  for (let f = 0; f < p.nf; f++) {
    const start = p.loopOff[f], count = p.loopOff[f + 1] - start, i0 = 3 * p.loops[start];
    const a0 = v[i0] - ox, a1 = v[i0 + 1] - oy, a2 = v[i0 + 2] - oz;
    for (let q = 1; q + 1 < count; q++) {
      const i1 = 3 * p.loops[start + q], i2 = 3 * p.loops[start + q + 1];
      const b0 = v[i1] - ox, b1 = v[i1 + 1] - oy, b2 = v[i1 + 2] - oz;
      const c0 = v[i2] - ox, c1 = v[i2 + 1] - oy, c2 = v[i2 + 2] - oz;
      const det = (a0 * (b1 * c2 - b2 * c1) + a1 * (b2 * c0 - b0 * c2)) + a2 * (b0 * c1 - b1 * c0);
      six += det;
      sx += det * ((a0 + b0) + c0);
      sy += det * ((a1 + b1) + c1);
      sz += det * ((a2 + b2) + c2);
    }
  }
  if (six === 0) {
    out[o] = 0; out[o + 1] = ox; out[o + 2] = oy; out[o + 3] = oz;
    return;
  }
  const quad = 4.0 * six;
  out[o] = six / 6.0;
  out[o + 1] = ox + sx / quad;
  out[o + 2] = oy + sy / quad;
  out[o + 3] = oz + sz / quad;
}

function before(k, i, j) { // keys k: (x, y, index) triples; whether entry i comes before entry j
  const px = k[3 * i], py = k[3 * i + 1], qx = k[3 * j], qy = k[3 * j + 1];
  const hp = py < 0 || (py === 0 && px < 0) ? 1 : 0, hq = qy < 0 || (qy === 0 && qx < 0) ? 1 : 0;
  if (hp !== hq) return hp < hq;
  const cross = px * qy - py * qx;
  if (cross !== 0) return cross > 0;
  const dp = px * px + py * py, dq = qx * qx + qy * qy;
  if (dp !== dq) return dp < dq;
  return k[3 * i + 2] < k[3 * j + 2];
}

const SAME = 0, EMPTY = 1, DONE = 2;

function clipPoly(w, src, dst, plane, po, eps) {
  let plus = false, minus = false;
  for (let i = 0; i < src.nv; i++) {
    const s = dot3(plane, po, src.v, 3 * i) - plane[po + 3];
    w.dist[i] = s;
    const side = s > eps ? 1 : (s < -eps ? -1 : 0);
    w.side[i] = side;
    if (side === 1) plus = true;
    else if (side === -1) minus = true;
  }
  if (!plus) return SAME;
  if (!minus) return EMPTY;
  let nv = 0, ncross = 0;
  for (let i = 0; i < src.nv; i++) {
    if (w.side[i] <= 0) {
      w.renumber[i] = nv;
      dst.v[3 * nv] = src.v[3 * i]; dst.v[3 * nv + 1] = src.v[3 * i + 1]; dst.v[3 * nv + 2] = src.v[3 * i + 2];
      nv++;
    } else {
      w.renumber[i] = -1;
    }
  }
  const keptVertices = nv;
  let nf = 0, nl = 0;
  dst.loopOff[0] = 0;
  for (let f = 0; f < src.nf; f++) {
    const first = src.loopOff[f], count = src.loopOff[f + 1] - first, start = nl;
    if (nf + 2 > w.fcap) throw new AlignedError('clip buffers exceeded');
    for (let t = 0; t < count; t++) {
      const a = src.loops[first + t], b = src.loops[first + (t + 1 < count ? t + 1 : 0)];
      if (nl + 2 > w.lcap) throw new AlignedError('clip buffers exceeded');
      if (w.side[a] <= 0) dst.loops[nl++] = w.renumber[a];
      if (w.side[a] * w.side[b] === -1) {
        const lo = a < b ? a : b, hi = a < b ? b : a;
        let index = -1;
        for (let c = 0; c < ncross; c++) if (w.cross[3 * c] === lo && w.cross[3 * c + 1] === hi) { index = w.cross[3 * c + 2]; break; }
        if (index < 0) {
          if (nv >= w.vcap) throw new AlignedError('clip buffers exceeded');
          const tc = w.dist[lo] / (w.dist[lo] - w.dist[hi]);
          for (let c = 0; c < 3; c++) dst.v[3 * nv + c] = src.v[3 * lo + c] + (src.v[3 * hi + c] - src.v[3 * lo + c]) * tc;
          index = nv++;
          w.cross[3 * ncross] = lo; w.cross[3 * ncross + 1] = hi; w.cross[3 * ncross + 2] = index;
          ncross++;
        }
        dst.loops[nl++] = index;
      }
    }
    if (nl - start >= 3) {
      for (let c = 0; c < 4; c++) dst.plane[4 * nf + c] = src.plane[4 * f + c];
      dst.isnew[nf] = src.isnew[f];
      dst.loopOff[++nf] = nl;
    } else {
      nl = start;
    }
  }
  w.used.fill(0, 0, nv);
  for (let i = 0; i < nl; i++) w.used[dst.loops[i]] = 1;
  let npoints = 0;
  for (let i = 0; i < src.nv; i++) if (w.side[i] === 0 && w.used[w.renumber[i]]) w.points[npoints++] = w.renumber[i];
  for (let i = keptVertices; i < nv; i++) if (w.used[i]) w.points[npoints++] = i;
  dst.nv = nv;
  if (npoints >= 3) {
    if (nl + npoints > w.lcap) throw new AlignedError('clip buffers exceeded');
    let cx = 0, cy = 0, cz = 0;
    for (let i = 0; i < npoints; i++) {
      const x = 3 * w.points[i];
      cx = cx + dst.v[x]; cy = cy + dst.v[x + 1]; cz = cz + dst.v[x + 2];
    }
    cx = cx / npoints; cy = cy / npoints; cz = cz / npoints;
    const basis = w.basis, keys = w.keys;
    planeBasis(plane, po, basis);
    for (let i = 0; i < npoints; i++) {
      const x = 3 * w.points[i];
      const d0 = dst.v[x] - cx, d1 = dst.v[x + 1] - cy, d2 = dst.v[x + 2] - cz;
      keys[3 * i] = (d0 * basis[0] + d1 * basis[1]) + d2 * basis[2];
      keys[3 * i + 1] = (d0 * basis[3] + d1 * basis[4]) + d2 * basis[5];
      keys[3 * i + 2] = w.points[i];
    }
    for (let j = 1; j < npoints; j++) {
      const ix = keys[3 * j], iy = keys[3 * j + 1], ii = keys[3 * j + 2];
      let k = j - 1;
      // the item sits at slot j until placed: compare with a copy in the spare slot npoints
      keys[3 * npoints] = ix; keys[3 * npoints + 1] = iy; keys[3 * npoints + 2] = ii;
      while (k >= 0 && before(keys, npoints, k)) {
        keys[3 * (k + 1)] = keys[3 * k]; keys[3 * (k + 1) + 1] = keys[3 * k + 1]; keys[3 * (k + 1) + 2] = keys[3 * k + 2];
        k--;
      }
      keys[3 * (k + 1)] = ix; keys[3 * (k + 1) + 1] = iy; keys[3 * (k + 1) + 2] = ii;
    }
    for (let i = 0; i < npoints; i++) dst.loops[nl++] = keys[3 * i + 2];
    for (let c = 0; c < 4; c++) dst.plane[4 * nf + c] = plane[po + c];
    dst.isnew[nf] = 1;
    dst.loopOff[++nf] = nl;
  }
  dst.nf = nf;
  dst.nl = nl;
  return DONE;
}

function clipCorners(w, input, count, out, plane, po, eps) {
  let plus = false, minus = false;
  const dist = w.cdist, side = w.cside;
  for (let i = 0; i < count; i++) {
    dist[i] = dot3(plane, po, input, 8 * i) - plane[po + 3];
    side[i] = dist[i] > eps ? 1 : (dist[i] < -eps ? -1 : 0);
    if (side[i] === 1) plus = true;
    else if (side[i] === -1) minus = true;
  }
  if (!plus) {
    out.set(input.subarray(0, 8 * count));
    return count;
  }
  if (!minus) return 0;
  let n = 0;
  for (let t = 0; t < count; t++) {
    const u = t + 1 < count ? t + 1 : 0;
    if (n + 2 > w.ccap) throw new AlignedError('clip buffers exceeded');
    if (side[t] <= 0) {
      for (let c = 0; c < 8; c++) out[8 * n + c] = input[8 * t + c];
      n++;
    }
    if (side[t] * side[u] === -1) {
      const weight = dist[t] / (dist[t] - dist[u]), p = 8 * n++;
      for (let c = 0; c < 8; c++) out[p + c] = input[8 * t + c] + (input[8 * u + c] - input[8 * t + c]) * weight;
      const length = Math.sqrt((out[p + 3] * out[p + 3] + out[p + 4] * out[p + 4]) + out[p + 5] * out[p + 5]);
      if (length > 0) {
        out[p + 3] = out[p + 3] / length; out[p + 4] = out[p + 4] / length; out[p + 5] = out[p + 5] / length;
      }
    }
  }
  return n;
}

function bisector(sites, i, j, out, o) {
  const n0 = sites[3 * j] - sites[3 * i], n1 = sites[3 * j + 1] - sites[3 * i + 1], n2 = sites[3 * j + 2] - sites[3 * i + 2];
  const length = Math.sqrt((n0 * n0 + n1 * n1) + n2 * n2);
  if (length === 0) throw new AlignedError('aligned fracture: scale is too small for this pattern (two sites coincide)');
  const u0 = n0 / length, u1 = n1 / length, u2 = n2 / length;
  const m0 = (sites[3 * i] + sites[3 * j]) * 0.5, m1 = (sites[3 * i + 1] + sites[3 * j + 1]) * 0.5;
  const m2 = (sites[3 * i + 2] + sites[3 * j + 2]) * 0.5;
  out[o] = u0; out[o + 1] = u1; out[o + 2] = u2;
  out[o + 3] = (u0 * m0 + u1 * m1) + u2 * m2;
}

function nearest(sites, x, xo, cells, count) {
  let best = cells[0], bestD = Infinity;
  for (let k = 0; k < count; k++) {
    const w = 3 * cells[k];
    const dx = x[xo] - sites[w], dy = x[xo + 1] - sites[w + 1], dz = x[xo + 2] - sites[w + 2];
    const dd = (dx * dx + dy * dy) + dz * dz;
    if (dd < bestD) { best = cells[k]; bestD = dd; }
  }
  return best;
}

// ------------------------------------------------------------------------------------ the cut

function placeSites(data, pattern, point, direction, scale) {
  const a = data.arrays, lo = a.pattern_site_offsets[pattern], hi = a.pattern_site_offsets[pattern + 1];
  const m = Math.max(Math.abs(direction[0]), Math.abs(direction[1]), Math.abs(direction[2]));
  const s0 = direction[0] / m, s1 = direction[1] / m, s2 = direction[2] / m;
  const length = Math.sqrt((s0 * s0 + s1 * s1) + s2 * s2);
  const d = [s0 / length, s1 / length, s2 / length], uv = new Float64Array(6);
  planeBasis(d, 0, uv);
  const sites = new Float64Array(3 * (hi - lo));
  for (let i = 0; i < hi - lo; i++) {
    const x = a.pattern_sites;
    const t0 = scale * x[3 * (lo + i)], t1 = scale * x[3 * (lo + i) + 1], t2 = scale * x[3 * (lo + i) + 2];
    for (let c = 0; c < 3; c++) sites[3 * i + c] = point[c] + ((t0 * uv[c] + t1 * uv[3 + c]) + t2 * d[c]);
  }
  // the boundary: n' = (n0 u + n1 v) + n2 d, h' = scale h + n' . point
  const bp = a.boundary_planes, B = bp.rows, boundary = new Float64Array(4 * B);
  for (let b = 0; b < B; b++) {
    for (let c = 0; c < 3; c++) boundary[4 * b + c] = (bp[4 * b] * uv[c] + bp[4 * b + 1] * uv[3 + c]) + bp[4 * b + 2] * d[c];
    boundary[4 * b + 3] = scale * bp[4 * b + 3] + dot3(boundary, 4 * b, point, 0);
  }
  return { sites, boundary, B };
}

function makePart(piece, whole, poly, mass, mo) {
  const part = { piece, whole, volume: mass[mo], centroid: [mass[mo + 1], mass[mo + 2], mass[mo + 3]] };
  if (!whole) {
    part.vertices = poly.v.slice(0, 3 * poly.nv);
    part.planes = poly.plane.slice(0, 4 * poly.nf);
    part.isNew = poly.isnew.slice(0, poly.nf);
    part.loopOffsets = poly.loopOff.slice(0, poly.nf + 1);
    part.loops = poly.loops.slice(0, poly.nl);
  }
  return part;
}

function pushPolygon(out, cell, material, corners, count) {
  let list = out.tris.get(cell);
  if (!list) { list = { values: new Float64Array(24 * 64), materials: new Int32Array(64), n: 0 }; out.tris.set(cell, list); }
  for (let q = 1; q + 1 < count; q++) {
    if (list.n === list.materials.length) { // grow both by doubling
      const values = new Float64Array(2 * list.values.length), materials = new Int32Array(2 * list.materials.length);
      values.set(list.values);
      materials.set(list.materials);
      list.values = values;
      list.materials = materials;
    }
    const o = 24 * list.n;
    list.values.set(corners.subarray(0, 8), o);
    list.values.set(corners.subarray(8 * q, 8 * q + 16), o + 8);
    list.materials[list.n++] = material;
  }
}

function addPart(out, cell, part) {
  let list = out.parts.get(cell);
  if (!list) { list = []; out.parts.set(cell, list); }
  list.push(part);
}

function clipBy(w, src, planes, po, count, c, r, eps) {
  let cur = src;
  for (let e = 0; e < count; e++) {
    const o = po + 4 * e;
    if (dot3(planes, o, c, 0) - planes[o + 3] < -r) continue;
    const next = cur === w.buf[1] ? w.buf[2] : w.buf[1];
    const res = clipPoly(w, cur, next, planes, o, eps);
    if (res === EMPTY) return null;
    if (res === DONE) cur = next;
  }
  return cur;
}

// A convex polygon into the Voronoi cells of `cells`' sites (docs/FORMAT.md section 13.4, step 7): whole when
// every corner has the same nearest site, else split by the bisector of the cells of corner 0 and of the first
// other corner, each side going on without the other cell.
function splitPolygon(hit, polygon, count, cells, eps, material, out) {
  const sites = hit.sites, first = nearest(sites, polygon, 0, cells, cells.length);
  let other = -1;
  for (let q = 1; q < count && other < 0; q++) {
    const cell = nearest(sites, polygon, 8 * q, cells, cells.length);
    if (cell !== first) other = cell;
  }
  if (other < 0) { pushPolygon(out, first, material, polygon, count); return; }
  const plane = new Float64Array(8);
  bisector(sites, first, other, plane, 0);
  for (let c = 0; c < 4; c++) plane[4 + c] = -plane[c];
  const size = 8 * (2 * count + 2);
  const near = hit.pool.length ? hit.pool.pop() : new Float64Array(size);
  const far = hit.pool.length ? hit.pool.pop() : new Float64Array(size);
  const nearBuf = near.length >= size ? near : new Float64Array(size), farBuf = far.length >= size ? far : new Float64Array(size);
  const nn = clipCorners(hit.w, polygon, count, nearBuf, plane, 0, eps);
  const nf = clipCorners(hit.w, polygon, count, farBuf, plane, 4, eps);
  if (nn >= 3) splitPolygon(hit, nearBuf, nn, cells.filter((c) => c !== other), eps, material, out);
  if (nf >= 3) splitPolygon(hit, farBuf, nf, cells.filter((c) => c !== first), eps, material, out);
  hit.pool.push(nearBuf, farBuf); // buffers for the next splits (a call's buffers are free once it returns)
}

function cutPiece(data, k, hit, out) {
  const a = data.arrays, w = data.work, mass = data.pieceMass, { sites, S, planes, nbOff, boundary, B } = hit;
  const c = [a.piece_sphere[4 * k], a.piece_sphere[4 * k + 1], a.piece_sphere[4 * k + 2]], r = a.piece_sphere[4 * k + 3];
  const outer = S, ts = new Float64Array(B);
  const whole = (cell) => { addPart(out, cell, makePart(k, true, null, mass, 4 * k)); out.whole.push([cell, k]); };
  let straddle = false;
  for (let b = 0; b < B; b++) {
    ts[b] = dot3(boundary, 4 * b, c, 0) - boundary[4 * b + 3];
    if (ts[b] > r) { whole(outer); return; }
    if (ts[b] >= -r) straddle = true;
  }
  const dists = hit.dists;
  let best = Infinity;
  for (let i = 0; i < S; i++) {
    const dx = c[0] - sites[3 * i], dy = c[1] - sites[3 * i + 1], dz = c[2] - sites[3 * i + 2];
    dists[i] = Math.sqrt((dx * dx + dy * dy) + dz * dz);
    if (dists[i] < best) best = dists[i];
  }
  const bound = best + 2.0 * r;
  let cells = [];
  for (let i = 0; i < S; i++) if (dists[i] <= bound) cells.push(i);
  const pv = a.piece_vertex_offsets, vx = a.piece_vertices, v0 = 3 * pv[k], nvert = pv[k + 1] - pv[k];
  if (!straddle) {
    if (cells.length > 1) {
      const first = nearest(sites, vx, v0, cells, cells.length);
      let same = true;
      for (let i = 1; i < nvert && same; i++) same = nearest(sites, vx, v0 + 3 * i, cells, cells.length) === first;
      if (same) cells = [first];
    }
    if (cells.length === 1) { whole(cells[0]); return; }
  }
  const eps = EPS_RELATIVE * r, keep = KEEP_RELATIVE * mass[4 * k];
  const base = w.buf[0];
  piecePoly(data, k, base);
  const made = [], inner = [], m4 = new Float64Array(4);
  const record = (cell, poly) => {
    polyMass(poly, m4, 0);
    if (m4[0] > keep) { made.push([cell, makePart(k, false, poly, m4, 0)]); return true; }
    return false;
  };
  for (const i of cells) {
    let empty = false;
    for (let e = nbOff[i]; e < nbOff[i + 1] && !empty; e++) empty = dot3(planes, 4 * e, c, 0) - planes[4 * e + 3] > r;
    for (let e = nbOff[i]; e < nbOff[i + 1] && !empty; e++) { // or every corner lies beyond a plane
      let least = Infinity;
      for (let v = 0; v < base.nv && least > eps; v++) least = Math.min(least, dot3(planes, 4 * e, base.v, 3 * v) - planes[4 * e + 3]);
      empty = least > eps;
    }
    if (empty) continue;
    let cur = clipBy(w, base, planes, 4 * nbOff[i], nbOff[i + 1] - nbOff[i], c, r, eps);
    for (let e = hit.wallOff[i]; cur && straddle && e < hit.wallOff[i + 1]; e++) {
      cur = clipBy(w, cur, boundary, 4 * hit.walls[e], 1, c, r, eps); // the boundary planes of cell i
    }
    if (cur && record(i, cur)) inner.push(i);
  }
  let hasOuter = false;
  if (straddle) {
    let cur = base;
    const flipped = new Float64Array(4);
    for (let b = 0; b < B; b++) {
      if (ts[b] < -r) continue;
      for (let e = 0; e < 4; e++) flipped[e] = -boundary[4 * b + e];
      const next = cur === w.buf[1] ? w.buf[2] : w.buf[1];
      let res = clipPoly(w, cur, next, flipped, 0, eps);
      if (res !== EMPTY && record(outer, res === SAME ? cur : next)) hasOuter = true;
      res = clipPoly(w, cur, next, boundary, 4 * b, eps);
      if (res === EMPTY) break;
      if (res === DONE) cur = next;
    }
  }
  if (made.length <= 1) {
    whole(made.length ? made[0][0] : nearest(sites, vx, v0, cells, cells.length));
    return;
  }
  for (const [i, part] of made) addPart(out, i, part);
  const nk = inner.length;
  const pos = a.triangle_positions, nrm = a.triangle_normals, uvs = a.triangle_uvs;
  const pt = a.piece_triangle_offsets, mat = a.triangle_materials;
  let polygon = hit.triA, spare = hit.triB;
  const beyond = hit.triC, flipped = new Float64Array(4);
  for (let t = pt[k]; t < pt[k + 1]; t++) {
    for (let q = 0; q < 3; q++) {
      for (let e = 0; e < 3; e++) {
        polygon[8 * q + e] = pos[9 * t + 3 * q + e];
        polygon[8 * q + 3 + e] = nrm[9 * t + 3 * q + e];
      }
      polygon[8 * q + 6] = uvs[6 * t + 2 * q];
      polygon[8 * q + 7] = uvs[6 * t + 2 * q + 1];
    }
    let count = 3;
    if (hasOuter) {
      for (let b = 0; b < B && count > 0; b++) {
        for (let e = 0; e < 4; e++) flipped[e] = -boundary[4 * b + e];
        const nb = clipCorners(w, polygon, count, beyond, flipped, 0, eps);
        if (nb >= 3) pushPolygon(out, outer, mat[t], beyond, nb);
        count = clipCorners(w, polygon, count, spare, boundary, 4 * b, eps);
        const swap = polygon;
        polygon = spare;
        spare = swap;
      }
    }
    if (count < 3) continue;
    if (nk === 0) { pushPolygon(out, outer, mat[t], polygon, count); continue; }
    splitPolygon(hit, polygon, count, inner, eps, mat[t], out);
  }
  const corners = w.corners[0];
  for (const [i, part] of made) {
    for (let f = 0; f < part.isNew.length; f++) {
      if (!part.isNew[f]) continue;
      const start = part.loopOffsets[f], count = part.loopOffsets[f + 1] - start;
      for (let q = 0; q < count; q++) {
        const x = 3 * part.loops[start + q];
        for (let e = 0; e < 3; e++) {
          corners[8 * q + e] = part.vertices[x + e];
          corners[8 * q + 3 + e] = part.planes[4 * f + e];
        }
        boxUv(part.vertices, x, part.planes, 4 * f, data.uvScale, corners, 8 * q + 6);
      }
      pushPolygon(out, i, data.interiorMaterial, corners, count);
    }
  }
}

/**
 * New fragments for a hit (docs/FORMAT.md sections 13.3-13.4).
 * @param {object} data from loadAligned
 * @param {number[]} point the hit, model space
 * @param {number[]} direction the impulse (its direction: finite, not zero)
 * @param {number} [scale] model units per pattern unit (default: the file's defaultScale)
 * @param {number} [pattern] which pattern (default 0)
 * @returns {{fragments: object[]}} per fragment, in increasing cell order: `cell`, `parts` (piece order:
 *   `{piece, whole, volume, centroid}` plus, for cut parts, `vertices` (Float64Array n*3), `planes` (f*4),
 *   `isNew` (f), `loopOffsets` (f+1), `loops`), `wholePieces` (pieces whose stored triangles it shows),
 *   `triangles` (Float64Array t*24: per corner x y z nx ny nz u v), `materials` (Int32Array t),
 *   `volume`, `centerOfMass`
 */
export function alignedFracture(data, point, direction, scale = data.defaultScale, pattern = 0) {
  if (!point || point.length !== 3 || !point.every((x) => Number.isFinite(x))) throw new AlignedError('aligned fracture: point must be 3 finite numbers');
  const m = direction ? Math.max(Math.abs(direction[0]), Math.abs(direction[1]), Math.abs(direction[2])) : NaN;
  if (!(Number.isFinite(m) && m > 0)) throw new AlignedError('aligned fracture: direction must be finite and not zero');
  if (!(Number.isFinite(scale) && scale > 0)) throw new AlignedError('aligned fracture: scale must be finite and > 0');
  if (!Number.isInteger(pattern) || pattern < 0 || pattern >= data.patterns) throw new AlignedError(`aligned fracture: pattern ${pattern} does not exist`);
  const a = data.arrays, { sites, boundary, B } = placeSites(data, pattern, point, direction, scale);
  const lo = a.pattern_site_offsets[pattern], S = a.pattern_site_offsets[pattern + 1] - lo;
  const cn = a.cell_neighbor_offsets, nbOff = new Int32Array(S + 1);
  for (let i = 0; i <= S; i++) nbOff[i] = cn[lo + i] - cn[lo];
  const planes = new Float64Array(4 * nbOff[S]);
  for (let i = 0; i < S; i++) {
    for (let e = nbOff[i]; e < nbOff[i + 1]; e++) bisector(sites, i, a.cell_neighbors[cn[lo] + e], planes, 4 * e);
  }
  const out = { parts: new Map(), tris: new Map(), whole: [] };
  const ccap = data.work.ccap;
  const bo = a.cell_boundary_offsets, wallOff = new Int32Array(S + 1);
  for (let i = 0; i <= S; i++) wallOff[i] = bo[lo + i] - bo[lo];
  const hit = { w: data.work, sites, S, planes, nbOff, boundary, B, wallOff, dists: new Float64Array(S), pool: [], walls: a.cell_boundary.subarray(bo[lo]), triA: new Float64Array(8 * ccap),
    triB: new Float64Array(8 * ccap), triC: new Float64Array(8 * ccap) };
  for (let k = 0; k < data.pieces; k++) cutPiece(data, k, hit, out);
  const fragments = [];
  for (const cell of [...out.parts.keys()].sort((x, y) => x - y)) {
    const parts = out.parts.get(cell);
    let volume = 0;
    const moment = [0, 0, 0];
    for (const part of parts) {
      volume += part.volume;
      for (let c = 0; c < 3; c++) moment[c] += part.volume * part.centroid[c];
    }
    const tris = out.tris.get(cell) || { values: new Float64Array(0), materials: new Int32Array(0), n: 0 };
    fragments.push({
      cell, parts, wholePieces: out.whole.filter(([c]) => c === cell).map(([, k]) => k),
      triangles: tris.values.slice(0, 24 * tris.n), materials: tris.materials.slice(0, tris.n), volume,
      centerOfMass: moment.map((x) => (volume > 0 ? x / volume : 0)),
    });
  }
  return { fragments };
}
