// `fracture view`: the "cut at the click" mode (aligned fracture, docs/FORMAT.md section 13).
//
// When a bake has its companion file (<stem>.aligned.json + .bin, `--set aligned.enabled=true`), the
// panel offers a mode in which a click does not choose among the baked fragments: the JavaScript reader
// (engines/web/fracture_aligned.js) places a fracture pattern at the click, oriented by the hit
// direction, cuts the asset's convex pieces with it and the page shows the new fragments, which then
// drift apart from the hit (the rest of the object stays). Each click cuts the intact asset again.
// Kept apart from app.js (a few hook lines there): load(), active, cut(), reset(), summary().

import * as THREE from 'three';
import { alignedFracture, getPiece, loadAligned } from './vendor/fracture_aligned.js';

const DURATION = 1.2; // seconds of drift
const INTERIOR = new THREE.Color(0xb08060);

function palette(n) {
  return Array.from({ length: n }, (_, i) => new THREE.Color().setHSL((i * 0.61803398875) % 1, 0.5, 0.6));
}

export class AlignedMode {
  /**
   * @param {import('./scene.js').FragmentScene} scene
   * @param {HTMLElement} panel the side panel: a section is added to it, shown when the asset has the file
   */
  constructor(scene, panel) {
    this.scene = scene;
    this.data = null;
    this.group = new THREE.Group();
    this.last = null;
    this.motion = null;
    this.section = document.createElement('section');
    this.section.hidden = true;
    this.section.innerHTML = `
      <h2>Cut at the click</h2>
      <label class="row"><input id="aligned-on" type="checkbox"> aligned fracture (new pieces at the hit)</label>
      <label class="row">pattern size <input id="aligned-scale" type="range" min="0.25" max="3" step="0.05" value="1"></label>
      <label class="row">pattern <select id="aligned-pattern"></select></label>
      <div id="aligned-info" class="info"></div>`;
    const hitSection = panel.querySelector('section');
    panel.insertBefore(this.section, hitSection ? hitSection.nextSibling : null);
    this.checkbox = this.section.querySelector('#aligned-on');
    this.checkbox.addEventListener('change', () => this.reset());
    scene.onFrame.push((now) => this._animate(now));
  }

  /** Whether clicks cut at the click. */
  get active() {
    return this.data !== null && this.checkbox.checked;
  }

  /** Load the asset's companion file (`url` of its .aligned.json with the page's version query), or none. */
  async load(url, query = '') {
    this.reset();
    this.data = null;
    this.section.hidden = true;
    if (!url) return;
    const header = await (await fetch(url + query)).text();
    const uri = JSON.parse(header).buffer.uri;
    const binary = await (await fetch(`files/${encodeURIComponent(uri)}${query}`)).arrayBuffer();
    this.data = loadAligned(header, binary);
    const select = this.section.querySelector('#aligned-pattern');
    select.replaceChildren(...Array.from({ length: this.data.patterns }, (_, q) => {
      const info = this.data.patternInfo[q] || {};
      return new Option(`${q + 1}${info.sites ? ` (${info.sites} cells)` : ''}`, String(q));
    }));
    this.section.hidden = false;
    this.section.querySelector('#aligned-info').textContent =
      `${this.data.pieces} convex pieces, ${this.data.patterns} pattern(s); click the object to cut it there`;
  }

  /** Cut the intact asset at `point` (model space) along `direction` (unit); shows and returns the fragments. */
  cut(point, direction) {
    const scale = this.data.defaultScale * Number(this.section.querySelector('#aligned-scale').value);
    const pattern = Number(this.section.querySelector('#aligned-pattern').value) || 0;
    const t0 = performance.now();
    const result = alignedFracture(this.data, [point.x, point.y, point.z], [direction.x, direction.y, direction.z], scale, pattern);
    const ms = performance.now() - t0;
    this._show(result.fragments, point);
    this.last = { point: [point.x, point.y, point.z], direction: [direction.x, direction.y, direction.z], scale, pattern, ms,
      fragments: result.fragments.map((f) => ({ cell: f.cell, volume: f.volume, parts: f.parts.length,
        triangles: f.materials.length + f.wholePieces.reduce((s, k) => s + getPiece(this.data, k).triangleCount, 0) })) };
    this.section.querySelector('#aligned-info').textContent =
      `${result.fragments.length} new fragments, ${result.fragments.reduce((s, f) => s + f.parts.length, 0)} convex parts, cut in ${ms.toFixed(1)} ms`;
    return this.last;
  }

  /** Back to the baked fragments. */
  reset() {
    this.group.removeFromParent();
    for (const mesh of this.group.children) mesh.geometry.dispose();
    this.group.clear();
    this.motion = null;
    this.scene.root.visible = true;
  }

  summary() {
    return this.last;
  }

  _show(fragments, point) {
    this.reset();
    const a = this.data.arrays, colors = palette(fragments.length);
    const material = new THREE.MeshStandardMaterial({ vertexColors: true, side: THREE.DoubleSide, roughness: 0.8 });
    const rest = fragments.reduce((best, f) => (f.volume > best.volume ? f : best), fragments[0]);
    const offsets = [];
    fragments.forEach((f, index) => {
      let count = f.materials.length;
      for (const k of f.wholePieces) count += getPiece(this.data, k).triangleCount;
      const positions = new Float32Array(9 * count), normals = new Float32Array(9 * count), rgb = new Float32Array(9 * count);
      let t = 0;
      const put = (material, write) => {
        const color = material === this.data.interiorMaterial ? INTERIOR : colors[index];
        write(t);
        for (let c = 0; c < 3; c++) rgb.set([color.r, color.g, color.b], 9 * t + 3 * c);
        t++;
      };
      for (const k of f.wholePieces) {
        const piece = getPiece(this.data, k);
        for (let s = piece.triangleFirst; s < piece.triangleFirst + piece.triangleCount; s++) {
          put(a.triangle_materials[s], (i) => {
            positions.set(a.triangle_positions.subarray(9 * s, 9 * s + 9), 9 * i);
            normals.set(a.triangle_normals.subarray(9 * s, 9 * s + 9), 9 * i);
          });
        }
      }
      for (let s = 0; s < f.materials.length; s++) {
        put(f.materials[s], (i) => {
          for (let c = 0; c < 3; c++) {
            for (let e = 0; e < 3; e++) {
              positions[9 * i + 3 * c + e] = f.triangles[24 * s + 8 * c + e];
              normals[9 * i + 3 * c + e] = f.triangles[24 * s + 8 * c + 3 + e];
            }
          }
        });
      }
      const geometry = new THREE.BufferGeometry();
      geometry.setAttribute('position', new THREE.BufferAttribute(positions, 3));
      geometry.setAttribute('normal', new THREE.BufferAttribute(normals, 3));
      geometry.setAttribute('color', new THREE.BufferAttribute(rgb, 3));
      const mesh = new THREE.Mesh(geometry, material);
      this.group.add(mesh);
      // Away from the hit, faster for the small ones; the largest fragment (the rest) stays.
      const away = new THREE.Vector3(...f.centerOfMass).sub(point);
      const distance = away.length() || 1;
      const speed = f === rest ? 0 : this.scene.diagonal * 0.15 / Math.cbrt(Math.max(f.volume / rest.volume, 1e-6));
      offsets.push(away.multiplyScalar(Math.min(speed, 0.4 * this.scene.diagonal) / distance));
    });
    this.scene.scene.add(this.group);
    this.scene.root.visible = false;
    this.motion = { start: performance.now() / 1000, offsets };
  }

  _animate(now) {
    if (!this.motion) return;
    const t = Math.min(1, (now - this.motion.start) / DURATION);
    const eased = 1 - (1 - t) * (1 - t);
    this.group.children.forEach((mesh, i) => mesh.position.copy(this.motion.offsets[i]).multiplyScalar(eased));
    if (t >= 1) this.motion = null;
  }
}
