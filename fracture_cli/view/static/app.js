// `fracture view`: the page. Polls /api/state, loads the chosen asset (runtime file with the
// JavaScript reader, GLB with three.js, report), wires the panel, and runs hits on the object's
// damage state (docs/FORMAT.md section 12: one per loaded object, fresh after a reset or a load).
// window.fractureTest exposes what the end-to-end test reads back (tests/test_view_e2e.py).

import * as THREE from 'three';
import { loadRuntime } from './vendor/fracture_runtime.js';
import { FragmentScene } from './scene.js';
import { launch, poseAt, projectHit } from './hit.js';
import { formatNumber, hitHtml, reportHtml } from './panel.js';
import { AlignedMode } from './aligned.js'; // aligned fracture: "cut at the click" (aligned.js)

const $ = (id) => document.getElementById(id);
const scene = new FragmentScene($('canvas'));
const aligned = new AlignedMode(scene, $('panel')); // aligned fracture (aligned.js)
const state = {
  assets: [], stem: null, version: null, runtime: null, report: null, loading: false,
  hit: null, damage: null, flight: null, flightStart: 0, thresholdTouched: false, reloads: 0, error: null,
};

function setStatus(text, isError = false) {
  $('status').textContent = text;
  $('status').classList.toggle('error', isError);
}

// ---------------------------------------------------------------- log sliders with number boxes

function linkLogSlider(rangeId, numberId, onChange) {
  const range = $(rangeId);
  const number = $(numberId);
  range.addEventListener('input', () => {
    number.value = formatNumber(10 ** Number(range.value));
    onChange();
  });
  number.addEventListener('change', () => {
    const value = Number(number.value);
    if (value > 0) range.value = Math.log10(value);
    onChange();
  });
}

function readNumber(id, fallback) {
  const value = Number($(id).value);
  return Number.isFinite(value) && value >= 0 ? value : fallback;
}

function setLogValue(rangeId, numberId, value) {
  $(numberId).value = formatNumber(value);
  if (value > 0) $(rangeId).value = Math.log10(value);
}

linkLogSlider('magnitude-range', 'magnitude', () => {});
linkLogSlider('threshold-range', 'threshold', () => { state.thresholdTouched = true; });

// ---------------------------------------------------------------- colours

function palette(n) {
  return Array.from({ length: n }, (_, i) => new THREE.Color().setHSL((i * 0.61803398875) % 1, 0.55, 0.58));
}

// Colour mode "structure": fragments bonded to the world, and the others from healthy to weak.
const ANCHOR_COLOR = new THREE.Color(0x3d7be0);
const HEALTHY_COLOR = new THREE.Color(0xc8c8c8);
const WEAK_COLOR = new THREE.Color(0xd2402a);

/** Per fragment: the lowest health of its bonds that still hold (1 without any, or before a hit). */
function fragmentHealth(runtime, health) {
  const lowest = new Array(runtime.numFragments).fill(1);
  for (let m = 0; m < runtime.numEdges; m++) {
    if (health[m] <= 0) continue;
    for (const j of [runtime.edges[2 * m], runtime.edges[2 * m + 1]]) lowest[j] = Math.min(lowest[j], health[m]);
  }
  return lowest;
}

function isStructure(runtime) {
  return runtime.anchored !== null || runtime.damage !== null;
}

function coolwarm(t) {  // t in [-1, 1]: blue, grey, red; square-root ramp so small values still show
  const a = new THREE.Color(0x3b4cc0);
  const mid = new THREE.Color(0xc8c8c8);
  const b = new THREE.Color(0xb40426);
  const amount = Math.sqrt(Math.min(1, Math.abs(t)));
  return t < 0 ? mid.clone().lerp(a, amount) : mid.clone().lerp(b, amount);
}

/** Per-fragment value of mode i: W[i, j] (d = 1), or the signed length of W[i, j, :] (d = 3). */
function modeValues(runtime, i) {
  const { numFragments: p, dim: d, W } = runtime;
  const values = [];
  for (let j = 0; j < p; j++) {
    const o = (i * p + j) * d;
    values.push(d === 1 ? W[o] : Math.sign(W[o] || 1) * Math.hypot(W[o], W[o + 1], W[o + 2]));
  }
  return values;
}

function applyColors() {
  const mode = $('color-mode').value;
  const rt = state.runtime;
  if (!rt || mode === 'materials') {
    scene.setFragmentColors(null);
    return;
  }
  if (mode === 'structure') {
    const health = fragmentHealth(rt, state.damage);
    scene.setFragmentColors(health.map((h, j) => (rt.anchored && rt.anchored[j] === 1
      ? ANCHOR_COLOR.clone() : HEALTHY_COLOR.clone().lerp(WEAK_COLOR, 1 - h))));
  } else if (mode === 'fragments') {
    scene.setFragmentColors(palette(rt.numFragments));
  } else if (mode === 'groups') {
    const groups = state.hit ? state.hit.groups : Array.from(rt.groups());
    const ids = [...new Set(groups)];
    const colors = palette(ids.length);
    scene.setFragmentColors(groups.map((g) => colors[ids.indexOf(g)]));
  } else {
    const values = modeValues(rt, Number(mode.slice(5)));
    const scale = Math.max(1e-30, ...values.map(Math.abs));
    scene.setFragmentColors(values.map((v) => coolwarm(v / scale)));
  }
}

// A structure (anchors or damage) starts in its own colours: what holds to the world and what is weakened.
function fillColorModes(runtime, newAsset) {
  const select = $('color-mode');
  const previous = select.value;
  const options = [['materials', 'baked materials'], ['fragments', 'fragments'], ['groups', 'groups (last hit)']];
  if (isStructure(runtime)) options.push(['structure', 'structure (anchored, health)']);
  for (let i = 0; i < runtime.numModes; i++) options.push([`mode-${i}`, `mode ${i + 1} of ${runtime.numModes}`]);
  select.innerHTML = options.map(([value, label]) => `<option value="${value}">${label}</option>`).join('');
  const fallback = isStructure(runtime) && newAsset ? 'structure' : 'materials';
  select.value = !newAsset && options.some(([value]) => value === previous) ? previous : fallback;
}

// ---------------------------------------------------------------- loading and reloading

async function loadAsset(asset, { keepCamera = false } = {}) {
  state.loading = true;
  const version = asset.version;
  setStatus(`loading ${asset.stem}…`);
  try {
    const query = `?v=${version}`;
    const runtime = await loadRuntime(`files/${encodeURIComponent(asset.files['fracture.json'])}${query}`);
    let report = null;
    if (asset.files['report.json']) {
      const response = await fetch(`files/${encodeURIComponent(asset.files['report.json'])}${query}`);
      if (response.ok) report = await response.json();
    }
    const info = await scene.load(`files/${encodeURIComponent(asset.files.glb)}${query}`, runtime.fragmentNames, { keepCamera });
    // aligned fracture: the companion file, when the bake wrote one (aligned.js)
    await aligned.load(asset.files['aligned.json'] ? `files/${encodeURIComponent(asset.files['aligned.json'])}` : null, query);
    const sameAsset = state.stem === asset.stem;
    Object.assign(state, { stem: asset.stem, version, runtime, report, hit: null, damage: runtime.newState(), flight: null,
      error: null });
    if (!sameAsset || !state.thresholdTouched) {
      state.thresholdTouched = false;
      setLogValue('threshold-range', 'threshold', runtime.defaultThreshold);
    }
    scene.setExplode(Number($('explode').value));
    scene.setBondEdges(runtime.edges);
    scene.setBondsVisible($('bonds').checked);
    $('collision-row').hidden = info.collisionCount === 0;
    $('collision-count').textContent = info.collisionCount ? `(${info.collisionCount})` : '';
    scene.setCollisionVisible($('collision').checked && info.collisionCount > 0);
    fillColorModes(runtime, !sameAsset);
    applyColors();
    $('report').innerHTML = reportHtml(asset.stem, runtime, report);
    $('hit-info').textContent = 'click on the object to hit it';
    state.reloads += 1;
    setStatus(`${asset.stem}: ${runtime.numFragments} fragments, ${runtime.numModes} modes`);
    if (location.hash.slice(1) !== asset.stem) history.replaceState(null, '', `#${encodeURIComponent(asset.stem)}`);
  } catch (err) {
    // A bake may be rewriting the files right now: keep what is shown, retry on the next change.
    state.error = String(err.message || err);
    state.version = version;
    if (state.stem === null) state.stem = asset.stem;
    setStatus(`${asset.stem}: ${state.error}`, true);
  } finally {
    state.loading = false;
  }
}

function fillPicker(assets) {
  const select = $('asset');
  const names = assets.map((a) => a.stem).join('\n');
  if (select.dataset.names === names) return;
  select.dataset.names = names;
  select.replaceChildren(...assets.map((a) => new Option(a.stem, encodeURIComponent(a.stem))));
  if (state.stem) select.value = encodeURIComponent(state.stem);
}

async function poll() {
  let body;
  try {
    body = await (await fetch('api/state', { cache: 'no-store' })).json();
  } catch {
    setStatus('the fracture view server is not answering (stopped?)', true);
    return;
  }
  state.assets = body.assets.filter((a) => a.missing.length === 0);
  fillPicker(state.assets);
  if (state.loading) return;
  if (!state.assets.length) {
    setStatus(body.error || `no baked assets in ${body.folder} yet; waiting for a bake`, Boolean(body.error));
    return;
  }
  const wanted = state.stem || decodeURIComponent(location.hash.slice(1)) || state.assets[0].stem;
  const asset = state.assets.find((a) => a.stem === wanted) || state.assets[0];
  if (asset.stem !== state.stem) await loadAsset(asset);
  else if (asset.version !== state.version && asset.settled) await loadAsset(asset, { keepCamera: true });
}

$('asset').addEventListener('change', () => {
  const stem = decodeURIComponent($('asset').value);
  const asset = state.assets.find((a) => a.stem === stem);
  if (asset) loadAsset(asset);
});

// ---------------------------------------------------------------- hits

// Back to the object as loaded: a fresh damage state, nothing moved, no cracks.
function resetHit() {
  aligned.reset(); // aligned fracture (aligned.js)
  Object.assign(state, { hit: null, damage: state.runtime ? state.runtime.newState() : null, flight: null });
  scene.setGroupMotion(null);
  scene.setBrokenBonds(null);
  scene.setCracks([]);
  scene.clearHit();
  applyColors();
  $('hit-info').textContent = 'click on the object to hit it';
}

function hitAt(clientX, clientY) {
  const rt = state.runtime;
  if (!rt) return null;
  const pick = scene.pick(clientX, clientY);
  if (!pick) return null;
  const byView = document.querySelector('input[name=direction]:checked').value === 'view';
  const direction = (byView ? pick.rayDirection : pick.normal.clone().negate()).normalize();
  if (aligned.active) { // aligned fracture: cut the asset at the click instead (aligned.js)
    scene.showHit(pick.point, direction, pick.point);
    return aligned.cut(pick.point, direction);
  }
  const magnitude = readNumber('magnitude', 1);
  const threshold = readNumber('threshold', rt.defaultThreshold);
  // Successive hits damage the object's state; otherwise each hit starts from a fresh one (which the
  // next successive hit then continues).
  const damage = $('accumulate').checked ? state.damage : rt.newState();
  const hit = projectHit(rt, damage, pick.point, direction.clone().multiplyScalar(magnitude), threshold);
  hit.fragment = rt.fragmentNames[pick.fragment];
  Object.assign(state, { hit, damage });
  const site = new THREE.Vector3(rt.sites[3 * hit.site], rt.sites[3 * hit.site + 1], rt.sites[3 * hit.site + 2]);
  scene.setGroupMotion(null);
  scene.showHit(pick.point, direction, site);
  scene.setBrokenBonds(hit.broken, hit.health);
  scene.setCracks(crackLines(rt, hit.cracked));
  const masses = state.report && state.report.fragments && state.report.fragments.length === rt.numFragments
    ? state.report.fragments.map((f) => Math.abs(f.volume)) : scene.fragments.map((f) => f.boxVolume);
  state.flight = launch(hit.groups, hit.anchored, scene.explodedCentroids(), scene.explodedBottoms(), masses, hit.displacement, rt.dim,
    direction, scene.diagonal);
  state.flightStart = performance.now() / 1000;
  state.flightDone = false;
  applyColors();
  $('hit-info').innerHTML = hitHtml(hit, rt.fragmentNames, rt);
  return hit;
}

/** The crack segments of the cracked bonds, each with the fragment it moves with (empty without crack arrays). */
function crackLines(runtime, cracked) {
  const lines = [];
  cracked.forEach((isCracked, m) => {
    if (!isCracked) return;
    const points = runtime.crackSegmentsOf(m);
    for (let i = 0; i < points.length; i += 6) lines.push({ fragment: runtime.edges[2 * m], points: points.subarray(i, i + 6) });
  });
  return lines;
}

scene.onFrame.push((now) => {
  if (!state.flight || state.flightDone) return;
  const pose = poseAt(state.flight, state.hit.groups, now - state.flightStart);
  scene.setGroupMotion(pose.matrices);
  state.flightDone = pose.done;
});

$('reset').addEventListener('click', resetHit);
$('explode').addEventListener('input', () => {
  scene.setExplode(Number($('explode').value));
  if (state.hit) resetHit();
});
$('interior').addEventListener('change', () => scene.setInterior($('interior').checked));
$('bonds').addEventListener('change', () => scene.setBondsVisible($('bonds').checked));
$('collision').addEventListener('change', () => scene.setCollisionVisible($('collision').checked));
$('color-mode').addEventListener('change', applyColors);

// Click (not drag) hits; hover names the fragment.
const canvas = $('canvas');
let down = null;
canvas.addEventListener('pointerdown', (event) => { down = event.button === 0 ? [event.clientX, event.clientY] : null; });
canvas.addEventListener('pointerup', (event) => {
  if (down && Math.hypot(event.clientX - down[0], event.clientY - down[1]) < 4) hitAt(event.clientX, event.clientY);
  down = null;
});
canvas.addEventListener('pointermove', (event) => {
  const tooltip = $('tooltip');
  const pick = state.runtime && !event.buttons ? scene.pick(event.clientX, event.clientY) : null;
  if (!pick) {
    tooltip.hidden = true;
    return;
  }
  const j = pick.fragment;
  let text = state.runtime.fragmentNames[j];
  if (state.hit) text += ` · group_${String(state.hit.groups[j]).padStart(3, '0')}`;
  const mode = $('color-mode').value;
  if (mode === 'structure') {
    const held = state.runtime.anchored && state.runtime.anchored[j] === 1 ? ' · anchored' : '';
    text += `${held} · health ${formatNumber(fragmentHealth(state.runtime, state.damage)[j])}`;
  }
  if (mode.startsWith('mode-')) text += ` · W = ${formatNumber(modeValues(state.runtime, Number(mode.slice(5)))[j])}`;
  tooltip.textContent = text;
  const rect = canvas.getBoundingClientRect();
  tooltip.style.left = `${event.clientX - rect.left + 14}px`;
  tooltip.style.top = `${event.clientY - rect.top + 10}px`;
  tooltip.hidden = false;
});
canvas.addEventListener('pointerleave', () => { $('tooltip').hidden = true; });

// ---------------------------------------------------------------- test hook

window.fractureTest = {
  get ready() { return state.runtime !== null && !state.loading; },
  get asset() { return state.stem; },
  get version() { return state.version; },
  get reloads() { return state.reloads; },
  get error() { return state.error; },
  get lastHit() { return state.hit && { ...state.hit, displacement: Array.from(state.hit.displacement) }; },
  get animationDone() { return !state.flight || state.flightDone === true; },
  screenPoint: (point) => scene.screenPoint(point),
  model: () => ({ center: scene.center.toArray(), diagonal: scene.diagonal, fragments: state.runtime.fragmentNames.slice(),
    collisionShapes: scene.collisionObjects.length }),
  hitAtScreen: (x, y) => hitAt(x, y),
  // A structure's state as drawn: colour per fragment (hex), crack lines, how far each fragment moved,
  // the damage state and the panel's lowest health.
  structure: () => ({
    features: state.runtime.features.slice(),
    anchored: state.runtime.anchored ? Array.from(state.runtime.anchored) : null,
    colorMode: $('color-mode').value,
    colors: scene.colors ? scene.colors.map((c) => c.getHex()) : null,
    anchorColor: ANCHOR_COLOR.getHex(),
    crackLines: scene.crackSegments.map(({ fragment, points }) => ({ fragment, points: Array.from(points) })),
    moved: scene.movedDistances(),
    health: Array.from(state.damage),
    lowestHealth: $('lowest-health') ? Number($('lowest-health').textContent) : null,
  }),
  aligned: { get available() { return aligned.data !== null; }, setActive: (on) => { aligned.checkbox.checked = on; },
    get last() { return aligned.summary(); } }, // aligned fracture (aligned.js)
};

poll();
setInterval(poll, 1000);
