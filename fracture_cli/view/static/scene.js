// The 3D side of `fracture view`: the fragments of one bake, their poses, colours, picking,
// the bond lines, crack lines, collision shapes and the hit markers. Knows nothing about the runtime file.
//
// Coordinates: a bake's GLB places every fragment node at its pivot in the asset's model
// space, and the page adds no transform, so "rest" world coordinates are model coordinates.
// Every fragment's pose is  world = G (group motion) * T(explode offset) * restWorld.

import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';

const INTERIOR_MATERIAL = 'interior';
// Collision parts the "gameready" export adds as child nodes (Godot and Unreal conventions).
const COLLISION_NAME = /-convcolonly$|^UCX_/;
const BOND_INTACT = new THREE.Color(0xffe28a);
const BOND_BROKEN = new THREE.Color(0xff4030);
const CRACK_COLOR = 0x101010;
// Fragment surfaces are drawn a little behind their depth so that crack lines lying on them stay visible.
const SURFACE_OFFSET = { polygonOffset: true, polygonOffsetFactor: 1, polygonOffsetUnits: 1 };

export class FragmentScene {
  constructor(canvas) {
    this.canvas = canvas;
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(0x2b2f36);
    this.camera = new THREE.PerspectiveCamera(40, 1, 0.01, 100);
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.enableDamping = false;
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x444450, 1.6));
    const key = new THREE.DirectionalLight(0xffffff, 2.0);
    key.position.set(0.6, 1.0, 0.8);
    const fill = new THREE.DirectionalLight(0xffffff, 0.6);
    fill.position.set(-0.8, 0.3, -0.6);
    this.scene.add(key, fill);
    this.root = new THREE.Group();
    this.markers = new THREE.Group();
    this.scene.add(this.root, this.markers);
    this.raycaster = new THREE.Raycaster();
    this.fragments = [];
    this.collisionObjects = [];
    this.bonds = null;
    this.cracks = null;
    this.crackSegments = [];  // [{fragment, points: 6 numbers}] drawn now, model space at rest
    this.colors = null;  // the fragments' colours (THREE.Color each) or null for the baked materials
    this.explode = 0;
    this.groupMotion = null;  // per fragment Matrix4 (group motion) or null at rest
    this.showInterior = true;
    this.onFrame = [];
    new ResizeObserver(() => this.resize()).observe(canvas);
    this.resize();
    const loop = (time) => {
      for (const callback of this.onFrame) callback(time / 1000);
      this.controls.update();
      this.renderer.render(this.scene, this.camera);
      requestAnimationFrame(loop);
    };
    requestAnimationFrame(loop);
  }

  resize() {
    const width = this.canvas.clientWidth || 1;
    const height = this.canvas.clientHeight || 1;
    this.renderer.setSize(width, height, false);
    this.camera.aspect = width / height;
    this.camera.updateProjectionMatrix();
  }

  /**
   * Load a bake's GLB; fragment j is the node named fragmentNames[j].
   * @returns {Promise<{collisionCount: number}>}
   */
  async load(url, fragmentNames, { keepCamera = false } = {}) {
    const gltf = await new GLTFLoader().loadAsync(url);
    const model = gltf.scene;
    model.updateMatrixWorld(true);
    this.root.clear();
    this.markers.clear();
    this.root.add(model);
    model.updateMatrixWorld(true);
    this.collisionObjects = await findCollisionObjects(gltf);
    const byName = new Map();
    model.traverse((object) => {
      if (object.name && !byName.has(object.name)) byName.set(object.name, object);
    });
    const missing = fragmentNames.filter((name) => !byName.has(THREE.PropertyBinding.sanitizeNodeName(name)));
    if (missing.length) {
      throw new Error(`${missing.length} of ${fragmentNames.length} fragments are missing from the GLB (first: ${missing[0]}); is it from the same bake?`);
    }
    this.fragments = fragmentNames.map((name, index) => this._fragment(byName.get(THREE.PropertyBinding.sanitizeNodeName(name)), name, index));
    const box = new THREE.Box3();
    for (const f of this.fragments) box.union(f.box);
    this.center = box.getCenter(new THREE.Vector3());
    this.diagonal = box.getSize(new THREE.Vector3()).length() || 1;
    this._makeFloor(box);
    this._makeBonds(null);
    this.setCracks([]);
    this.groupMotion = null;
    this.setInterior(this.showInterior);
    this.setCollisionVisible(false);
    this.applyPose();
    if (!keepCamera) this.frame();
    return { collisionCount: this.collisionObjects.length };
  }

  _fragment(node, name, index) {
    const meshes = [];
    node.traverse((object) => {
      if (object.isMesh && !isInside(object, this.collisionObjects)) meshes.push(object);
    });
    const box = new THREE.Box3();
    for (const mesh of meshes) {
      mesh.userData.fragment = index;
      mesh.userData.restWorld = mesh.matrixWorld.clone();
      // Two-sided: with the interior faces hidden, the inside of the shell shows instead of holes.
      if (mesh.material) Object.assign(mesh.material, { side: THREE.DoubleSide, ...SURFACE_OFFSET });
      mesh.userData.original = mesh.material;
      // 'interior', or '<stem>_interior' since bakes prefix names with the asset's stem.
      const material = mesh.material ? mesh.material.name || '' : '';
      mesh.userData.interior = material === INTERIOR_MATERIAL || material.endsWith('_' + INTERIOR_MATERIAL);
      mesh.geometry.computeBoundingBox();
      box.union(mesh.geometry.boundingBox.clone().applyMatrix4(mesh.matrixWorld));
    }
    node.matrixAutoUpdate = false;
    const size = box.getSize(new THREE.Vector3());
    return {
      index, name, node, meshes, box,
      centroid: box.getCenter(new THREE.Vector3()),
      boxVolume: size.x * size.y * size.z,
      restWorld: node.matrixWorld.clone(),
      parentInverse: node.parent.matrixWorld.clone().invert(),
      offset: new THREE.Vector3(),
    };
  }

  /** A faint grid under the object: where flying groups land. */
  _makeFloor(box) {
    if (this.floor) {
      this.scene.remove(this.floor);
      this.floor.geometry.dispose();
    }
    const size = this.diagonal * 4;
    this.floor = new THREE.GridHelper(size, 20, 0x4a505a, 0x3a3f47);
    this.floor.position.set(this.center.x, box.min.y, this.center.z);
    this.scene.add(this.floor);
  }

  /** Point the camera at the whole object from the front-right-above (+Y up, glTF convention). */
  frame() {
    const d = this.diagonal;
    const direction = new THREE.Vector3(1.0, 0.8, 1.4).normalize();
    this.camera.near = d / 200;
    this.camera.far = d * 50;
    this.camera.position.copy(this.center).addScaledVector(direction, 1.5 * d);
    this.camera.updateProjectionMatrix();
    this.controls.target.copy(this.center);
    this.controls.update();
  }

  setExplode(amount) {
    this.explode = amount;
    this.applyPose();
  }

  /** Exploded centroid of every fragment (rest centroid pushed away from the centre). */
  explodedCentroids() {
    return this.fragments.map((f) => f.centroid.clone().addScaledVector(f.centroid.clone().sub(this.center), this.explode));
  }

  /** Lowest y of every fragment in the exploded rest pose. */
  explodedBottoms() {
    return this.fragments.map((f) => f.box.min.y + (f.centroid.y - this.center.y) * this.explode);
  }

  /** Set each fragment node's matrix from the explode offset and the group motion. */
  applyPose() {
    const moved = new THREE.Matrix4();
    const centres = [];
    for (const f of this.fragments) {
      f.offset.copy(f.centroid).sub(this.center).multiplyScalar(this.explode);
      moved.makeTranslation(f.offset.x, f.offset.y, f.offset.z).multiply(f.restWorld);
      const centre = f.centroid.clone().add(f.offset);
      if (this.groupMotion) {
        moved.premultiply(this.groupMotion[f.index]);
        centre.applyMatrix4(this.groupMotion[f.index]);
      }
      f.node.matrix.copy(f.parentInverse).multiply(moved);
      f.node.matrixWorldNeedsUpdate = true;
      centres.push(centre);
    }
    this.root.updateMatrixWorld(true);
    this._updateBonds(centres);
    this._updateCracks();
  }

  /** Where fragment j's point `rest` (model space) is drawn now: explode offset, then group motion. */
  _posed(j, rest) {
    const f = this.fragments[j];
    const out = rest.clone().add(f.offset);
    return this.groupMotion ? out.applyMatrix4(this.groupMotion[j]) : out;
  }

  /** How far each fragment's centre is from where it rests (after the explode offset): 0 for a still one. */
  movedDistances() {
    return this.fragments.map((f) => this._posed(f.index, f.centroid).distanceTo(f.centroid.clone().add(f.offset)));
  }

  setGroupMotion(matrices) {
    this.groupMotion = matrices;
    this.applyPose();
  }

  setInterior(visible) {
    this.showInterior = visible;
    for (const f of this.fragments) for (const mesh of f.meshes) if (mesh.userData.interior) mesh.visible = visible;
  }

  setCollisionVisible(visible) {
    for (const object of this.collisionObjects) object.visible = visible;
  }

  /** Colour each fragment (array of THREE.Color, one per fragment), or null for the baked materials. */
  setFragmentColors(colors) {
    this.colors = colors;
    for (const f of this.fragments) {
      let outer = null;
      let inner = null;
      if (colors) {
        const side = THREE.DoubleSide;
        outer = new THREE.MeshStandardMaterial({ color: colors[f.index], roughness: 0.75, metalness: 0, side, ...SURFACE_OFFSET });
        inner = new THREE.MeshStandardMaterial({ color: colors[f.index].clone().multiplyScalar(0.55), roughness: 0.9, side, ...SURFACE_OFFSET });
      }
      for (const mesh of f.meshes) {
        const old = mesh.material;
        mesh.material = colors ? (mesh.userData.interior ? inner : outer) : mesh.userData.original;
        if (old !== mesh.userData.original && old !== mesh.material) old.dispose();
      }
    }
  }

  _makeBonds(edges) {
    if (this.bonds) {
      this.scene.remove(this.bonds);
      this.bonds.geometry.dispose();
    }
    this.bonds = null;
    this.edges = edges;
    if (!edges || edges.length === 0) return;
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(new Float32Array(edges.length * 3), 3));
    geometry.setAttribute('color', new THREE.BufferAttribute(new Float32Array(edges.length * 3), 3));
    const material = new THREE.LineBasicMaterial({ vertexColors: true, depthTest: false, transparent: true, opacity: 0.9 });
    this.bonds = new THREE.LineSegments(geometry, material);
    this.bonds.renderOrder = 10;
    this.bonds.visible = this.bondsVisible === true;
    this.bonds.frustumCulled = false;
    this.scene.add(this.bonds);
    this.setBrokenBonds(null);
    this.applyPose();
  }

  /** Show the fragment graph: edges is the runtime's Int32Array (e, 2). */
  setBondEdges(edges) {
    this._makeBonds(edges);
  }

  setBondsVisible(visible) {
    this.bondsVisible = visible;
    if (this.bonds) this.bonds.visible = visible;
  }

  /** Colour the bond lines: broken ones red, the others from intact yellow towards red as health (0..1) drops. */
  setBrokenBonds(broken, health = null) {
    if (!this.bonds) return;
    const colors = this.bonds.geometry.getAttribute('color');
    const c = new THREE.Color();
    for (let m = 0; m < this.edges.length / 2; m++) {
      if (broken && broken[m]) c.copy(BOND_BROKEN);
      else c.copy(BOND_INTACT).lerp(BOND_BROKEN, health ? 1 - health[m] : 0);
      colors.setXYZ(2 * m, c.r, c.g, c.b);
      colors.setXYZ(2 * m + 1, c.r, c.g, c.b);
    }
    colors.needsUpdate = true;
  }

  /**
   * Draw crack lines: segments [{fragment, points}] with 6 model-space numbers each (two ends at rest),
   * moving with their fragment (explode offset and group motion). An empty list removes them.
   */
  setCracks(segments) {
    if (this.cracks) {
      this.scene.remove(this.cracks);
      this.cracks.geometry.dispose();
      this.cracks = null;
    }
    this.crackSegments = segments;
    if (!segments.length) return;
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(new Float32Array(segments.length * 6), 3));
    this.cracks = new THREE.LineSegments(geometry, new THREE.LineBasicMaterial({ color: CRACK_COLOR }));
    this.cracks.frustumCulled = false;
    this.cracks.renderOrder = 9;
    this.scene.add(this.cracks);
    this._updateCracks();
  }

  _updateCracks() {
    if (!this.cracks) return;
    const positions = this.cracks.geometry.getAttribute('position');
    this.crackSegments.forEach(({ fragment, points }, i) => {
      for (let end = 0; end < 2; end++) {
        const rest = new THREE.Vector3(points[3 * end], points[3 * end + 1], points[3 * end + 2]);
        const at = this._posed(fragment, rest);
        positions.setXYZ(2 * i + end, at.x, at.y, at.z);
      }
    });
    positions.needsUpdate = true;
  }

  _updateBonds(centres) {
    if (!this.bonds) return;
    const positions = this.bonds.geometry.getAttribute('position');
    for (let i = 0; i < this.edges.length; i++) {
      const c = centres[this.edges[i]];
      positions.setXYZ(i, c.x, c.y, c.z);
    }
    positions.needsUpdate = true;
  }

  /** Meshes a click or hover may hit: fragments' visible meshes, never collision shapes. */
  _pickable() {
    const out = [];
    for (const f of this.fragments) for (const mesh of f.meshes) if (mesh.visible) out.push(mesh);
    return out;
  }

  /**
   * What is under a client (CSS pixel) position.
   * @returns {null|{fragment: number, point: THREE.Vector3, normal: THREE.Vector3, rayDirection: THREE.Vector3}}
   *   point and normal are mapped back to the rest pose (model space), whatever the current pose.
   */
  pick(clientX, clientY) {
    const rect = this.canvas.getBoundingClientRect();
    const ndc = new THREE.Vector2(((clientX - rect.left) / rect.width) * 2 - 1, -((clientY - rect.top) / rect.height) * 2 + 1);
    this.raycaster.setFromCamera(ndc, this.camera);
    const hits = this.raycaster.intersectObjects(this._pickable(), false);
    if (!hits.length) return null;
    const hit = hits[0];
    const mesh = hit.object;
    const toRest = mesh.userData.restWorld.clone().multiply(mesh.matrixWorld.clone().invert());
    const point = hit.point.clone().applyMatrix4(toRest);
    const normal = hit.face ? hit.face.normal.clone().transformDirection(mesh.userData.restWorld) : this.raycaster.ray.direction.clone().negate();
    return { fragment: mesh.userData.fragment, point, normal, rayDirection: this.raycaster.ray.direction.clone() };
  }

  /** Client (CSS pixel) position of a model-space point in the current view. */
  screenPoint(point) {
    const rect = this.canvas.getBoundingClientRect();
    const v = new THREE.Vector3(point[0], point[1], point[2]).project(this.camera);
    return { x: rect.left + ((v.x + 1) / 2) * rect.width, y: rect.top + ((1 - v.y) / 2) * rect.height, inFront: v.z < 1 };
  }

  /** Hit point, impulse arrow and nearest contact site markers (model space). */
  showHit(point, direction, site) {
    this.markers.clear();
    const d = this.diagonal;
    const ball = new THREE.Mesh(new THREE.SphereGeometry(d * 0.008, 16, 8), new THREE.MeshBasicMaterial({ color: 0xff3b30, depthTest: false }));
    ball.position.copy(point);
    ball.renderOrder = 11;
    const length = d * 0.25;
    const tail = point.clone().addScaledVector(direction, -length);
    const arrow = new THREE.ArrowHelper(direction, tail, length, 0xff3b30, length * 0.25, length * 0.12);
    const siteMark = new THREE.Mesh(new THREE.BoxGeometry(d * 0.008, d * 0.008, d * 0.008), new THREE.MeshBasicMaterial({ color: 0x40c0ff, depthTest: false }));
    siteMark.position.copy(site);
    siteMark.renderOrder = 11;
    this.markers.add(ball, arrow, siteMark);
  }

  clearHit() {
    this.markers.clear();
  }
}

function isInside(object, ancestors) {
  for (let o = object; o; o = o.parent) if (ancestors.includes(o)) return true;
  return false;
}

/**
 * Collision parts of a glTF: nodes named like Godot's "-convcolonly" or Unreal's "UCX_" parts, and
 * OMI_physics_body colliders whose OMI_physics_shape mesh no node draws. Drawn as wireframes, hidden at first.
 */
async function findCollisionObjects(gltf) {
  const found = [];
  const json = gltf.parser.json;
  const shapes = (json.extensions && json.extensions.OMI_physics_shape && json.extensions.OMI_physics_shape.shapes) || [];
  const drawnMeshes = new Set((json.nodes || []).filter((n) => COLLISION_NAME.test(n.name || '')).map((n) => n.mesh));
  const material = new THREE.MeshBasicMaterial({ color: 0x4cff7a, wireframe: true, transparent: true, opacity: 0.6, depthTest: false });
  const objects = [];
  gltf.scene.traverse((object) => objects.push(object));
  for (const object of objects) {
    if (COLLISION_NAME.test(object.name)) {
      found.push(object);
      continue;
    }
    const ext = object.userData.gltfExtensions || {};
    const body = ext.OMI_physics_body || {};
    const refs = [body.collider && body.collider.shape, body.trigger && body.trigger.shape, ext.OMI_physics_shape && ext.OMI_physics_shape.shape];
    for (const ref of refs) {
      const shape = Number.isInteger(ref) ? shapes[ref] : null;
      const meshIndex = shape && shape[shape.type] && shape[shape.type].mesh;
      if (!Number.isInteger(meshIndex) || drawnMeshes.has(meshIndex)) continue;
      const mesh = await gltf.parser.getDependency('mesh', meshIndex);
      mesh.name = `${object.name}-collider`;
      object.add(mesh);
      found.push(mesh);
    }
  }
  for (const object of found) {
    object.traverse((o) => {
      if (o.isMesh) {
        o.material = material;
        o.renderOrder = 5;
      }
    });
  }
  gltf.scene.updateMatrixWorld(true);
  return found;
}
