// The 3D view: every session's mesh tiles, trajectory and current pose, in world metres, Z up.
//
// All tiles share one material whose shader colours by height or by normal, so switching the
// colour mode, or the height range growing, costs one uniform write. The scene is rendered on
// every animation frame; nothing is allocated per frame.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

const FRAME_WINDOW = 120;        // animation frames in the frame-time statistics
const AXES_SIZE_M = 3;           // pose marker: axes length
const POSE_RADIUS_M = 0.6;       // pose marker: sphere radius
const TRAJECTORY_MIN_CAPACITY = 256;

export const COLOR_MODES = ['height', 'normal'];

const TILE_VERTEX_SHADER = /* glsl */ `
varying vec3 vWorld;
varying vec3 vNormal;
void main() {
  vec4 world = modelMatrix * vec4(position, 1.0);
  vWorld = world.xyz;
  vNormal = normalize(mat3(modelMatrix) * normal);
  gl_Position = projectionMatrix * viewMatrix * world;
}`;

const TILE_FRAGMENT_SHADER = /* glsl */ `
uniform int colorMode;   // 0: height ramp, 1: |normal| as RGB
uniform vec2 zRange;     // (lowest z, 1 / (highest z - lowest z))
uniform vec3 lightDir;   // towards the light, unit length
varying vec3 vWorld;
varying vec3 vNormal;

// Low to high: deep blue, teal, green, yellow, red.
vec3 heightRamp(float t) {
  const vec3 c0 = vec3(0.17, 0.22, 0.56);
  const vec3 c1 = vec3(0.11, 0.56, 0.74);
  const vec3 c2 = vec3(0.33, 0.73, 0.36);
  const vec3 c3 = vec3(0.94, 0.83, 0.27);
  const vec3 c4 = vec3(0.86, 0.31, 0.21);
  float s = clamp(t, 0.0, 1.0) * 4.0;
  if (s < 1.0) return mix(c0, c1, s);
  if (s < 2.0) return mix(c1, c2, s - 1.0);
  if (s < 3.0) return mix(c2, c3, s - 2.0);
  return mix(c3, c4, s - 3.0);
}

void main() {
  vec3 n = normalize(vNormal);
  if (!gl_FrontFacing) n = -n;
  float light = 0.45 + 0.55 * max(dot(n, lightDir), 0.0);
  vec3 base = colorMode == 0 ? heightRamp((vWorld.z - zRange.x) * zRange.y) : abs(n);
  gl_FragColor = vec4(base * light, 1.0);
}`;

// A stable colour per robot id, as a CSS string (the panel uses the same one).
export function robotCss(robot) {
  let h = 2166136261;  // FNV-1a, then a final mix so that ids differing in one letter differ
  for (let i = 0; i < robot.length; i++) {
    h ^= robot.charCodeAt(i);
    h = Math.imul(h, 16777619);
  }
  h ^= h >>> 16;
  h = Math.imul(h, 0x85ebca6b);
  h ^= h >>> 13;
  return `hsl(${(h >>> 0) % 360}, 75%, 60%)`;
}

// The WebGL renderer's name, and whether it rasterises on the CPU (SwiftShader, llvmpipe: headless
// browsers, machines without a GPU), where multisampling would double the cost of every frame.
function probeRenderer() {
  const gl = document.createElement('canvas').getContext('webgl2');
  if (!gl) return { name: 'none', software: false };
  const info = gl.getExtension('WEBGL_debug_renderer_info');
  const name = String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER));
  gl.getExtension('WEBGL_lose_context')?.loseContext();
  return { name, software: /swiftshader|llvmpipe|softpipe|software/i.test(name) };
}

// Once uploaded, a tile's arrays are no longer needed on the JS side.
function releaseArray() {
  this.array = null;
}

export class Viewer {
  constructor(container) {
    this.container = container;
    this.gl = probeRenderer();
    this.renderer = new THREE.WebGLRenderer({
      antialias: !this.gl.software,
      powerPreference: 'high-performance',
    });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    this.renderer.setClearColor(0x14171c);
    container.appendChild(this.renderer.domElement);

    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(50, 1, 0.1, 5000);
    this.camera.up.set(0, 0, 1);
    this.camera.position.set(-30, -40, 35);
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.enableDamping = true;
    this.controls.target.set(0, 0, 0);
    this.controls.screenSpacePanning = true;
    this.userMoved = false;
    this.controls.addEventListener('start', () => { this.userMoved = true; });

    this.tileMaterial = new THREE.ShaderMaterial({
      vertexShader: TILE_VERTEX_SHADER,
      fragmentShader: TILE_FRAGMENT_SHADER,
      side: THREE.DoubleSide,
      uniforms: {
        colorMode: { value: 0 },
        zRange: { value: new THREE.Vector2(0, 1) },
        lightDir: { value: new THREE.Vector3(0.35, 0.45, 0.82).normalize() },
      },
    });
    this.sphereGeometry = new THREE.SphereGeometry(POSE_RADIUS_M, 16, 12);

    this.grid = null;
    this.sceneRadius = 50;   // of the tiles last fitted, for the far plane
    this.clipDistance = -1;  // camera-to-target distance that near and far were set for
    this.robots = new Map();  // robot id -> { group, tiles, line, count, capacity, marker, ... }
    this.showTrajectories = true;
    this.zDirty = false;
    this.tileBox = new THREE.Box3();  // scratch for the height range and fitting

    // Frame times (ms between animation frames), a ring buffer, and a scratch copy for sorting.
    this.frameTimes = new Float64Array(FRAME_WINDOW);
    this.frameSorted = new Float64Array(FRAME_WINDOW);
    this.frameCount = 0;
    this.lastFrameAt = -1;

    this._resize();
    new ResizeObserver(() => this._resize()).observe(container);
    this.renderer.setAnimationLoop((t) => this._frame(t));
  }

  setColorMode(mode) {
    const index = COLOR_MODES.indexOf(mode);
    if (index >= 0) this.tileMaterial.uniforms.colorMode.value = index;
  }

  setTrajectoriesVisible(visible) {
    this.showTrajectories = visible;
    for (const r of this.robots.values()) r.line.visible = visible;
  }

  // Shows `geometry` as the tile `key` of `robot`, replacing (and disposing) what was there;
  // null removes the tile (an empty tile). The geometry must have positions and an index.
  setTile(robot, key, geometry) {
    const r = this._robot(robot);
    const old = r.tiles.get(key);
    if (old) {
      old.geometry.dispose();
      if (!geometry) {
        r.group.remove(old);
        r.tiles.delete(key);
      }
    }
    if (geometry) {
      geometry.computeVertexNormals();
      geometry.computeBoundingBox();
      geometry.computeBoundingSphere();
      for (const attribute of Object.values(geometry.attributes))
        if (attribute.isBufferAttribute) attribute.onUpload(releaseArray);
      if (geometry.index) geometry.index.onUpload(releaseArray);
      if (old) {
        old.geometry = geometry;
      } else {
        const mesh = new THREE.Mesh(geometry, this.tileMaterial);
        mesh.matrixAutoUpdate = false;  // tiles are in world coordinates
        r.group.add(mesh);
        r.tiles.set(key, mesh);
      }
    }
    this.zDirty = true;
  }

  // Removes every tile shown for a robot (its trajectory and pose stay), freeing their memory.
  clearTiles(robot) {
    const r = this.robots.get(robot);
    if (!r) return;
    for (const mesh of r.tiles.values()) {
      mesh.geometry.dispose();
      r.group.remove(mesh);
    }
    r.tiles.clear();
    this.zDirty = true;
  }

  // Appends sensor positions ([x, y, z] each) to the robot's trajectory line.
  appendTrajectory(robot, positions) {
    if (positions.length === 0) return;
    const r = this._robot(robot);
    if (r.count + positions.length > r.capacity) this._growTrajectory(r, r.count + positions.length);
    const attribute = r.line.geometry.attributes.position;
    const array = attribute.array;
    let o = r.count * 3;
    for (const p of positions) {
      array[o++] = p[0];
      array[o++] = p[1];
      array[o++] = p[2];
    }
    attribute.addUpdateRange(r.count * 3, positions.length * 3);
    attribute.needsUpdate = true;
    r.count += positions.length;
    r.line.geometry.setDrawRange(0, r.count);
  }

  // Places the robot's pose marker; a null pose hides it.
  setPose(robot, pose) {
    const r = this._robot(robot);
    if (!pose) {
      r.marker.visible = false;
      return;
    }
    const [x, y, z] = pose.position;
    const [qw, qx, qy, qz] = pose.orientation_wxyz;
    r.marker.position.set(x, y, z);
    r.marker.quaternion.set(qx, qy, qz, qw);
    r.marker.visible = true;
  }

  // Removes everything shown for a robot and frees its GPU memory.
  removeSession(robot) {
    const r = this.robots.get(robot);
    if (!r) return;
    for (const mesh of r.tiles.values()) mesh.geometry.dispose();
    r.line.geometry.dispose();
    r.line.material.dispose();
    r.axes.dispose();
    r.poseMaterial.dispose();
    this.scene.remove(r.group);
    this.robots.delete(robot);
    this.zDirty = true;
  }

  // Bounds of every tile shown, in `box`; false when no tile is shown.
  tileBounds(box) {
    box.makeEmpty();
    for (const r of this.robots.values())
      for (const mesh of r.tiles.values()) box.union(mesh.geometry.boundingBox);
    return !box.isEmpty();
  }

  // Points the camera at every tile shown, from the south-west and above.
  fit() {
    const box = this.tileBox;
    if (!this.tileBounds(box)) return false;
    const center = box.getCenter(new THREE.Vector3());
    const size = box.getSize(new THREE.Vector3());
    const radius = Math.max(size.length() / 2, 1);
    const distance = (1.15 * radius) / Math.sin(THREE.MathUtils.degToRad(this.camera.fov / 2));
    const direction = new THREE.Vector3(-0.55, -0.75, 0.65).normalize();
    this.camera.position.copy(center).addScaledVector(direction, distance);
    this.sceneRadius = radius;
    this.clipDistance = -1;  // near and far follow on the next frame
    this.controls.target.copy(center);
    this.controls.update();
    this._placeGrid(box);
    return true;
  }

  // Median and 95th percentile of the last FRAME_WINDOW frame times (ms); nulls before two frames.
  frameStats() {
    const n = Math.min(this.frameCount, FRAME_WINDOW);
    if (n === 0) return { median: null, p95: null };
    const sorted = this.frameSorted.subarray(0, n);
    sorted.set(this.frameTimes.subarray(0, n));
    sorted.sort();
    const at = (q) => sorted[Math.min(n - 1, Math.floor(q * n))];
    return { median: Math.round(at(0.5) * 100) / 100, p95: Math.round(at(0.95) * 100) / 100 };
  }

  // What the renderer holds and drew in the last frame: to watch for leaks and for cost.
  gpuStats() {
    const info = this.renderer.info;
    return {
      renderer: this.gl.name,
      antialias: !this.gl.software,
      geometries: info.memory.geometries,
      draw_calls: info.render.calls,
      triangles: info.render.triangles,
    };
  }

  _robot(robot) {
    let r = this.robots.get(robot);
    if (r) return r;
    const color = new THREE.Color().setStyle(robotCss(robot));
    const group = new THREE.Group();
    group.name = robot;
    const line = new THREE.Line(new THREE.BufferGeometry(), new THREE.LineBasicMaterial({ color }));
    line.frustumCulled = false;  // it grows; a cached bounding sphere would go stale
    line.visible = this.showTrajectories;
    const marker = new THREE.Group();
    const axes = new THREE.AxesHelper(AXES_SIZE_M);
    const poseMaterial = new THREE.MeshBasicMaterial({ color });
    marker.add(axes, new THREE.Mesh(this.sphereGeometry, poseMaterial));
    marker.visible = false;
    group.add(line, marker);
    this.scene.add(group);
    r = { group, tiles: new Map(), line, count: 0, capacity: 0, marker, axes, poseMaterial };
    this._growTrajectory(r, TRAJECTORY_MIN_CAPACITY);
    this.robots.set(robot, r);
    return r;
  }

  // Moves the trajectory into a buffer of at least `needed` points (doubling), on a new geometry:
  // a geometry's GPU buffer cannot change size.
  _growTrajectory(r, needed) {
    let capacity = Math.max(r.capacity, TRAJECTORY_MIN_CAPACITY);
    while (capacity < needed) capacity *= 2;
    const array = new Float32Array(capacity * 3);
    const old = r.line.geometry;
    if (r.count > 0) array.set(old.attributes.position.array.subarray(0, r.count * 3));
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(array, 3).setUsage(THREE.DynamicDrawUsage));
    geometry.setDrawRange(0, r.count);
    r.line.geometry = geometry;
    old.dispose();
    r.capacity = capacity;
  }

  // A ground grid under the data, 10 m cells (or 1 m for small scenes).
  _placeGrid(box) {
    const span = Math.max(box.max.x - box.min.x, box.max.y - box.min.y);
    const cell = span > 40 ? 10 : 1;
    const divisions = Math.min(Math.ceil((span * 1.2) / cell) + 1, 400);
    if (this.grid) {
      this.scene.remove(this.grid);
      this.grid.dispose();
    }
    this.grid = new THREE.GridHelper(divisions * cell, divisions, 0x3a414d, 0x2a2f38);
    this.grid.rotation.x = Math.PI / 2;  // GridHelper lies in XZ; the map's ground is XY
    this.grid.position.set((box.min.x + box.max.x) / 2, (box.min.y + box.max.y) / 2, box.min.z);
    this.scene.add(this.grid);
  }

  _updateHeightRange() {
    this.zDirty = false;
    const box = this.tileBox;
    if (!this.tileBounds(box)) return;
    const span = Math.max(box.max.z - box.min.z, 0.01);
    this.tileMaterial.uniforms.zRange.value.set(box.min.z, 1 / span);
  }

  _resize() {
    const w = Math.max(this.container.clientWidth, 1);
    const h = Math.max(this.container.clientHeight, 1);
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
  }

  _frame(now) {
    if (this.lastFrameAt >= 0) {
      this.frameTimes[this.frameCount % FRAME_WINDOW] = now - this.lastFrameAt;
      this.frameCount++;
    }
    this.lastFrameAt = now;
    if (this.zDirty) this._updateHeightRange();
    this.controls.update();
    this._updateClipPlanes();
    this.renderer.render(this.scene, this.camera);
  }

  // Near and far planes scaled to how far the camera is from what it orbits, so that both a
  // close look and the whole map keep their depth precision.
  _updateClipPlanes() {
    const d = this.camera.position.distanceTo(this.controls.target);
    if (Math.abs(d - this.clipDistance) <= 0.05 * this.clipDistance) return;
    this.clipDistance = d;
    this.camera.near = Math.max(d / 500, 0.01);
    this.camera.far = d * 20 + this.sceneRadius * 4;
    this.camera.updateProjectionMatrix();
  }
}
