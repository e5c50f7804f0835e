// Hits: project an impact with the runtime reader and fly the groups apart.
//
// The flight is a simple ballistic animation for judging a break, not a physics simulation:
// groups held by the world (feature "anchors") stay put, or without anchors the heaviest group
// does; every other group leaves along a blend of the impulse
// direction and the direction away from the heaviest group, faster when its projected
// displacement differs more from the heaviest group's, spins, falls under gravity and
// stops where its lowest point reaches the floor (the object's lowest point at rest).

import * as THREE from 'three';

const DURATION = 1.8;  // seconds
const GRAVITY = 2.0;  // object diagonals per second squared
const UP = new THREE.Vector3(0, 1, 0);  // glTF is +Y up

/**
 * One hit on a damage state (docs/FORMAT.md section 12.4; on a file without "damage" the state only
 * remembers broken bonds, so successive hits keep earlier breaks).
 * @param runtime  a FractureRuntime (fracture_runtime.js)
 * @param {Float64Array} damage  the state, updated in place: the object's (successive hits) or a fresh one
 * @param {THREE.Vector3} point  model space
 * @param {THREE.Vector3} impulse
 * @param {number} threshold
 */
export function projectHit(runtime, damage, point, impulse, threshold) {
  const before = Float64Array.from(damage);
  const result = runtime.hit(damage, [point.x, point.y, point.z], [impulse.x, impulse.y, impulse.z], threshold);
  return {
    point: [point.x, point.y, point.z],
    impulse: [impulse.x, impulse.y, impulse.z],
    threshold,
    site: result.site,
    siteBroken: Array.from(result.broken, (b, m) => b === 1 && before[m] > 0),  // by this hit
    broken: Array.from(result.broken, (b) => b === 1),  // by this hit and the state's earlier ones
    cracked: Array.from(result.cracked, (c) => c === 1),
    anchored: Array.from(result.anchored),
    health: Array.from(damage),
    groups: Array.from(result.groups),
    numGroups: result.numGroups,
    displacement: result.displacement,
  };
}

function hashUnit(seed) {
  // A deterministic pseudo-random unit vector per group, so a replayed hit looks the same.
  const s = Math.sin(seed * 12.9898 + 78.233) * 43758.5453;
  const a = (s - Math.floor(s)) * Math.PI * 2;
  const b = Math.sin(seed * 4.1414 + 1.7) * 0.9;
  return new THREE.Vector3(Math.cos(a) * Math.sqrt(1 - b * b), b, Math.sin(a) * Math.sqrt(1 - b * b)).normalize();
}

/**
 * Initial motion of every group.
 * @param {number[]} groups  group id per fragment
 * @param {number[]} anchored  per fragment: 1 when its group is held by the world (stays put)
 * @param {THREE.Vector3[]} centroids  (exploded) fragment centroids
 * @param {number[]} bottoms  lowest y of every (exploded) fragment; the lowest of all is the floor
 * @param {number[]} masses  per fragment (volume)
 * @param {Float64Array} displacement  (p * d) projected displacement of the hit
 * @param {number} dim  d
 * @param {THREE.Vector3} direction  unit impulse direction
 * @param {number} diagonal  object size
 */
export function launch(groups, anchored, centroids, bottoms, masses, displacement, dim, direction, diagonal) {
  const ids = [...new Set(groups)].sort((a, b) => a - b);
  const info = new Map(ids.map((g) => [g, { centre: new THREE.Vector3(), mass: 0, disp: new Array(dim).fill(0), count: 0, bottom: Infinity }]));
  const floor = Math.min(...bottoms);
  groups.forEach((g, j) => {
    const entry = info.get(g);
    entry.bottom = Math.min(entry.bottom, bottoms[j]);
    entry.centre.addScaledVector(centroids[j], masses[j]);
    entry.mass += masses[j];
    entry.count += 1;
    for (let c = 0; c < dim; c++) entry.disp[c] += displacement[j * dim + c];
  });
  for (const entry of info.values()) {
    entry.centre.divideScalar(entry.mass || 1);
    entry.disp = entry.disp.map((v) => v / entry.count);
  }
  const held = new Set(groups.filter((g, j) => anchored[j] === 1));
  // The group others fly away from: the heaviest held one, or without anchors the heaviest.
  const candidates = held.size ? ids.filter((g) => held.has(g)) : ids;
  const anchor = candidates.reduce((best, g) => (info.get(g).mass > info.get(best).mass ? g : best), candidates[0]);
  const base = info.get(anchor);
  const gap = (g) => Math.hypot(...info.get(g).disp.map((v, c) => v - base.disp[c]));
  const largest = Math.max(1e-300, ...ids.map(gap));
  const motion = new Map();
  for (const g of ids) {
    const entry = info.get(g);
    if (held.has(g)) {  // held by the world: never moves
      motion.set(g, { centre: entry.centre, fixed: true });
      continue;
    }
    if (ids.length === 1) {
      motion.set(g, { centre: entry.centre, shudder: true });
      continue;
    }
    if (g === anchor) {
      motion.set(g, { centre: entry.centre, fixed: true });
      continue;
    }
    const strength = gap(g) / largest;
    const away = entry.centre.clone().sub(base.centre);
    if (away.lengthSq() < 1e-12 * diagonal * diagonal) away.copy(direction);
    away.normalize();
    const heading = direction.clone().multiplyScalar(0.6).addScaledVector(away, 0.8).normalize();
    heading.y = Math.max(heading.y, 0.4);  // always tossed up a little: a group on the floor still moves
    heading.normalize();
    const velocity = heading.multiplyScalar(diagonal * (0.4 + 0.8 * strength));
    // Landing time: first t > 0 with v_y t - g t^2 / 2 = floor - bottom (<= 0).
    const g2 = GRAVITY * diagonal;
    const drop = Math.min(0, floor - entry.bottom);
    const land = (velocity.y + Math.sqrt(velocity.y * velocity.y - 2 * g2 * drop)) / g2;
    motion.set(g, { centre: entry.centre, velocity, land, spin: hashUnit(g + 1).multiplyScalar(1.5 + 3 * strength) });
  }
  return { motion, diagonal, anchor };
}

/**
 * Group motion matrices at time t (seconds after the hit): translate by v t + g t^2 / 2 and
 * rotate by spin * t about the group's centre, until the group lands. Returns one Matrix4 per fragment.
 */
export function poseAt(flight, groups, t) {
  const gravity = -GRAVITY * flight.diagonal;
  const perGroup = new Map();
  for (const [g, m] of flight.motion) {
    let matrix;
    if (m.fixed) {
      matrix = new THREE.Matrix4();
    } else if (m.shudder) {  // nothing broke: a short shudder
      const time = Math.min(t, DURATION);
      const wobble = Math.sin(time * 40) * Math.exp(-time * 4) * 0.01 * flight.diagonal;
      matrix = new THREE.Matrix4().makeTranslation(wobble, 0, 0);
    } else {
      const time = Math.min(t, DURATION, m.land);
      const shift = m.velocity.clone().multiplyScalar(time).addScaledVector(UP, 0.5 * gravity * time * time);
      const angle = m.spin.length() * time;
      const rotation = angle > 0 ? new THREE.Matrix4().makeRotationAxis(m.spin.clone().normalize(), angle) : new THREE.Matrix4();
      matrix = new THREE.Matrix4().makeTranslation(m.centre.x + shift.x, m.centre.y + shift.y, m.centre.z + shift.z)
        .multiply(rotation)
        .multiply(new THREE.Matrix4().makeTranslation(-m.centre.x, -m.centre.y, -m.centre.z));
    }
    perGroup.set(g, matrix);
  }
  return { matrices: groups.map((g) => perGroup.get(g)), done: t >= DURATION };
}
