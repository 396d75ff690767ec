/*
 * skinbus-view's page: the robot from its URDF, posed by the joint states, its skin patches on
 * their links coloured by state, and the contacts on them (docs/view.md has the protocol).
 *
 * Live:    index.html
 *          GET /api/scene, then the stream of JSON messages on ws://<host>/ws (reconnects every
 *          2 s while it is closed).
 * Replay:  index.html?replay=URL[&scene=URL][&speed=1]
 *          fetches URL, a JSON-lines file of stream messages (one object a line, e.g. the output
 *          of skinbus-host --json or skinbus-listen: contacts and patch_status; joint_state,
 *          heartbeat and hello lines too if present) and plays them at their recorded pace by
 *          stamp_us (speed times faster; lines without stamp_us go at once, in file order)
 *          instead of opening the WebSocket. The scene comes from `scene` (default /api/scene).
 *
 * Frames and units: the URDF is Z-up, in metres; three.js is Y-up, so the robot sits in a group
 * rotated -90 degrees about x. The robot object is the URDF's root link, the base frame the
 * host's contact positions are in: the contacts and their trails are its children. A patch's
 * mesh is a child of its link (the scene's grid is in the link's frame). The protocol's
 * millimetres become metres (/1000) at the one place each value enters the scene.
 *
 * For tests: window.skinbusView.summary() returns a JSON-able snapshot of what the page shows,
 * read back from its own scene graph (see summary() below).
 */

import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { CSS2DRenderer, CSS2DObject } from 'three/addons/renderers/CSS2DRenderer.js';
import URDFLoader from 'urdf-loader';

const MM = 0.001;                 // metres per millimetre
const STALL_MS = 2000;            // nothing from the host for this long: "stream stalled"
const RECONNECT_MS = 2000;        // WebSocket reconnection period
const TRAIL_POINTS = 40;          // positions kept per contact track
const TRAIL_FADE_MS = 1000;       // an ended track's trail fades out over this time
const MAX_EVENTS = 50;            // events listed in the panel
const MAX_ERRORS = 100;           // errors kept for summary()
const DETAILS_PERIOD_MS = 200;    // the selection's details are refreshed at most this often
const PATCH_LIFT_MM = 1.5;        // patches are drawn this far out of the skin

// Contact sphere radius (mm) from its depth (mm): visible at zero depth, growing with depth.
const contactRadiusMm = (depthMm) => 5 + 3 * Math.min(Math.max(depthMm, 0), 5);
// A contact's shear force (flag "shear") is drawn as an arrow from the contact along the force,
// this long per newton, from the sphere's surface.
const SHEAR_MM_PER_N = 12;

// Force colour ramp: the top stop is reached at FORCE_MAX_N and held above it.
const FORCE_MAX_N = 8;
const FORCE_STOPS = ['#2c7bb6', '#00a6ca', '#00ccbc', '#90eb9d', '#ffff8c', '#f9d057',
  '#f29e2e', '#e76818', '#d7191c'].map((c) => new THREE.Color(c));

const STATE_COLOURS = {
  online: '#2ecc40',
  degraded: '#ff851b',
  stale: '#ffdc00',
  offline: '#8a8a8a',
  discovering: '#3d8bfd',
  unknown: '#d8d8e8',   // no patch_status names the patch (yet)
};

// -- errors --------------------------------------------------------------------------------------

const errors = [];

function recordError(message) {
  const text = String(message);
  if (errors.length < MAX_ERRORS) errors.push(text);
  console.error('skinbus view:', text);
}

window.addEventListener('error', (e) => recordError(e.message || e));
window.addEventListener('unhandledrejection', (e) => recordError(e.reason?.message ?? e.reason));

// -- renderer, camera, lights --------------------------------------------------------------------

const viewEl = document.getElementById('view');

// WebGL drawn by the CPU (no GPU: SwiftShader, llvmpipe) spends most of each frame on
// multisampling; there the page draws without it, at one pixel per CSS pixel
// (docs/benchmarks/view.md).
function softwareRendering() {
  const gl = document.createElement('canvas').getContext('webgl2');
  const info = gl?.getExtension('WEBGL_debug_renderer_info');
  const name = info ? String(gl.getParameter(info.UNMASKED_RENDERER_WEBGL)) : '';
  gl?.getExtension('WEBGL_lose_context')?.loseContext();
  return /swiftshader|llvmpipe|softpipe|software/i.test(name);
}
const software = softwareRendering();
const renderer = new THREE.WebGLRenderer({ antialias: !software });
renderer.setPixelRatio(software ? 1 : Math.min(window.devicePixelRatio, 2));
viewEl.prepend(renderer.domElement);

const labelRenderer = new CSS2DRenderer();
labelRenderer.domElement.className = 'labels';
viewEl.append(labelRenderer.domElement);

const scene3d = new THREE.Scene();
scene3d.background = new THREE.Color('#23282e');

const camera = new THREE.PerspectiveCamera(40, 1, 0.01, 50);
camera.position.set(1.6, 1.2, -1.0);

const controls = new OrbitControls(camera, renderer.domElement);
controls.enableDamping = true;
controls.target.set(0, 0.35, 0);

scene3d.add(new THREE.HemisphereLight('#ffffff', '#50555c', 1.8));
const keyLight = new THREE.DirectionalLight('#ffffff', 1.8);
keyLight.position.set(3, 4, -2);           // in front of the robot (+x), above, to its left
scene3d.add(keyLight);
const fillLight = new THREE.DirectionalLight('#ffffff', 0.6);
fillLight.position.set(-2, 2, 3);
scene3d.add(fillLight);

// The URDF's Z-up world in three.js's Y-up one: base-frame (x, y, z) -> world (x, z, -y).
const zUp = new THREE.Group();
zUp.rotation.x = -Math.PI / 2;
scene3d.add(zUp);

function resize() {
  const w = Math.max(viewEl.clientWidth, 1);
  const h = Math.max(viewEl.clientHeight, 1);
  renderer.setSize(w, h);
  labelRenderer.setSize(w, h);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
}
new ResizeObserver(resize).observe(viewEl);
resize();

// -- robot ---------------------------------------------------------------------------------------

// The base frame: the URDF robot once loaded, a bare frame when there is none (no robot_url or
// it failed to load): contacts are still drawn where the host put them.
let base = new THREE.Object3D();
let robot = null;
zUp.add(base);

const contactsGroup = new THREE.Group();   // in the base frame
base.add(contactsGroup);

const jointsApplied = {};                  // joint name -> last value applied (rad or m)

async function loadRobot(url) {
  const loaded = await new URDFLoader().loadAsync(url);
  // body_map does not enforce joint limits when it places contacts: neither does the page.
  for (const joint of Object.values(loaded.joints)) joint.ignoreLimits = true;
  zUp.remove(base);
  zUp.add(loaded);
  loaded.add(contactsGroup);
  base = loaded;
  robot = loaded;
}

// Frame the robot: look at the middle of its bounding box from the front, left and above.
function frameCamera() {
  zUp.updateMatrixWorld(true);
  const box = new THREE.Box3().setFromObject(base);
  if (box.isEmpty()) return;
  const centre = box.getCenter(new THREE.Vector3());
  const size = box.getSize(new THREE.Vector3()).length();
  // Base-frame direction (1, 0.75, 0.45) (front, left, up) in the world's Y-up axes.
  const direction = new THREE.Vector3(1, 0.45, -0.75).normalize();
  camera.position.copy(centre).addScaledVector(direction, 1.5 * size);
  camera.near = size / 100;
  camera.far = size * 30;
  camera.updateProjectionMatrix();
  controls.target.copy(centre);
  controls.update();

  const floor = new THREE.GridHelper(Math.max(2, 3 * size), 20, '#4a525c', '#343a42');
  floor.position.set(centre.x, box.min.y, centre.z);
  scene3d.add(floor);
}

function applyJointState(msg) {
  if (!robot || !Array.isArray(msg.names) || !Array.isArray(msg.positions)) return;
  const n = Math.min(msg.names.length, msg.positions.length);
  for (let i = 0; i < n; i++) {
    const name = msg.names[i];
    if (!(name in robot.joints)) continue;   // a joint this URDF does not have
    robot.setJointValue(name, msg.positions[i]);
    jointsApplied[name] = msg.positions[i];
  }
}

// -- patches -------------------------------------------------------------------------------------

// Shared materials, one per state; a selected patch is more opaque and lit from within.
const patchMaterials = {};
const selectedPatchMaterials = {};
for (const [state, colour] of Object.entries(STATE_COLOURS)) {
  const material = new THREE.MeshLambertMaterial({
    color: colour,
    transparent: true,
    opacity: 0.6,
    side: THREE.DoubleSide,
    depthWrite: false,
  });
  patchMaterials[state] = material;
  selectedPatchMaterials[state] = material.clone();
  selectedPatchMaterials[state].opacity = 0.9;
  selectedPatchMaterials[state].emissive.set(colour).multiplyScalar(0.35);
}
const outlineMaterial = new THREE.LineBasicMaterial({ color: '#1b1f24' });
const selectedOutlineMaterial = new THREE.LineBasicMaterial({ color: '#ffffff' });

const patchViews = [];   // one per scene patch, in scene order

// One scene patch: its surface mesh and outline on its link, its latest status.
class PatchView {
  constructor(spec) {
    this.spec = spec;
    this.state = 'unknown';
    this.selected = false;
    this.status = null;          // the latest patch_status entry for it
    this.link = robot?.links[spec.link] ?? null;
    this.mesh = null;
    this.outline = null;
    if (!this.link) {
      if (robot) recordError(`patch ${spec.node}: link ${spec.link} is not in the robot`);
      return;
    }
    const { nu, nv, points_mm: points } = spec.grid ?? {};
    if (!(nu >= 2 && nv >= 2 && Array.isArray(points) && points.length === nu * nv)) {
      recordError(`patch ${spec.node}: malformed grid`);
      return;
    }

    // Row-major grid, point i * nv + j, link frame: metres.
    const positions = new Float32Array(nu * nv * 3);
    points.forEach((p, k) => positions.set([p[0] * MM, p[1] * MM, p[2] * MM], 3 * k));
    // Triangles wound u then v: their normals point out of the skin (the patch's +z).
    const triangles = [];
    for (let i = 0; i + 1 < nu; i++) {
      for (let j = 0; j + 1 < nv; j++) {
        const a = i * nv + j, b = (i + 1) * nv + j, c = b + 1, d = a + 1;
        triangles.push(a, b, d, b, c, d);
      }
    }
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(positions, 3));
    geometry.setIndex(triangles);
    geometry.computeVertexNormals();
    // Drawn PATCH_LIFT_MM proud of the skin: on the link's own surface (a faceted cylinder
    // around a faceted patch) it would be half hidden.
    const normals = geometry.attributes.normal.array;
    for (let k = 0; k < positions.length; k++) positions[k] += normals[k] * PATCH_LIFT_MM * MM;
    this.mesh = new THREE.Mesh(geometry, patchMaterials.unknown);
    this.mesh.userData.patch = this;
    this.link.add(this.mesh);

    // The border, walked round: v = min, u = max, v = max, u = min.
    const border = [];
    for (let j = 0; j < nv; j++) border.push(j);
    for (let i = 1; i < nu; i++) border.push(i * nv + nv - 1);
    for (let j = nv - 2; j >= 0; j--) border.push((nu - 1) * nv + j);
    for (let i = nu - 2; i > 0; i--) border.push(i * nv);
    const outlineGeometry = new THREE.BufferGeometry();
    outlineGeometry.setAttribute('position', new THREE.BufferAttribute(positions, 3));
    outlineGeometry.setIndex(border);
    this.outline = new THREE.LineLoop(outlineGeometry, outlineMaterial);
    this.link.add(this.outline);
  }

  setStatus(status) {
    this.status = status;
    this.state = status.state in STATE_COLOURS ? status.state : 'unknown';
    this.restyle();
  }

  setSelected(selected) {
    this.selected = selected;
    this.restyle();
  }

  restyle() {
    if (!this.mesh) return;
    this.mesh.material = (this.selected ? selectedPatchMaterials : patchMaterials)[this.state];
    this.outline.material = this.selected ? selectedOutlineMaterial : outlineMaterial;
  }

  // The scene's centre_mm through the page's own link transform, in the base frame, mm.
  centreBaseMm() {
    if (!this.link || !robot) return null;
    const c = this.spec.centre_mm;
    const p = new THREE.Vector3(c[0] * MM, c[1] * MM, c[2] * MM);
    this.link.localToWorld(p);
    robot.worldToLocal(p);
    return [p.x / MM, p.y / MM, p.z / MM];
  }
}

// The scene patch a patch_status entry is about: by hardware UID, else (a patch still
// discovering has none) by node ID, as the host places it.
function patchViewFor(status) {
  const uid = status.hardware_uid;
  if (uid && !/^0+$/.test(uid)) {
    const byUid = patchViews.find((v) => v.spec.hardware_uid === uid);
    if (byUid) return byUid;
  }
  return patchViews.find((v) => v.spec.node === status.node) ?? null;
}

// -- contacts ------------------------------------------------------------------------------------

const sphereGeometry = new THREE.SphereGeometry(1, 20, 14);    // unit: scaled to the radius
const selectionMarker = new THREE.Mesh(
  new THREE.SphereGeometry(1.35, 16, 10),
  new THREE.MeshBasicMaterial({ color: '#ffffff', wireframe: true }));

const contactViews = new Map();   // track_id -> ContactView, the latest message's contacts
const fadingViews = new Set();    // ended tracks whose trails are fading
const freeViews = [];             // views ready for a new track

// A contact track's sphere, label and trail. Views are reused from track to track: nothing is
// allocated per message.
class ContactView {
  constructor() {
    this.material = new THREE.MeshLambertMaterial({ color: '#ffffff' });
    this.sphere = new THREE.Mesh(sphereGeometry, this.material);
    this.sphere.userData.contact = this;
    this.labelEl = document.createElement('div');
    this.labelEl.className = 'contact-label';
    this.label = new CSS2DObject(this.labelEl);
    this.label.center.set(0, 1);           // the label's lower left corner at the centre
    this.sphere.add(this.label);

    this.trailPositions = new Float32Array(TRAIL_POINTS * 3);
    this.trailGeometry = new THREE.BufferGeometry();
    this.trailGeometry.setAttribute('position', new THREE.BufferAttribute(this.trailPositions, 3));
    // The trail: a line through its positions and a dot at each (lines are one pixel wide).
    this.trailMaterial = new THREE.LineBasicMaterial({ transparent: true, opacity: 0.9 });
    this.trailDotMaterial = new THREE.PointsMaterial({
      size: 3, sizeAttenuation: false, transparent: true, opacity: 0.9 });
    this.trail = new THREE.Line(this.trailGeometry, this.trailMaterial);
    this.trail.add(new THREE.Points(this.trailGeometry, this.trailDotMaterial));
    // Their bounding spheres would go stale as the trail moves: never culled.
    this.trail.frustumCulled = false;
    this.trail.children[0].frustumCulled = false;
    // The shear arrow (hidden unless the contact carries a shear force).
    this.arrow = new THREE.ArrowHelper(new THREE.Vector3(1, 0, 0), new THREE.Vector3(), 1,
                                       '#ffd23f');
    this.arrow.visible = false;
    contactsGroup.add(this.sphere, this.trail, this.arrow);
    this.reset();
  }

  reset() {
    this.data = null;            // the latest contact object
    this.stampUs = null;         // the stamp of the message it came in
    this.trailCount = 0;
    this.trailGeometry.setDrawRange(0, 0);
    this.setTrailOpacity(0.9);
    this.sphere.visible = false;
    this.trail.visible = false;
    this.arrow.visible = false;
    this.endedMs = 0;
  }

  update(contact, stampUs) {
    const trackChanged = this.data?.track_id !== contact.track_id;
    this.data = contact;
    this.stampUs = stampUs;
    const [x, y, z] = contact.position_mm;
    this.sphere.position.set(x * MM, y * MM, z * MM);
    this.sphere.scale.setScalar(contactRadiusMm(contact.depth_mm ?? 0) * MM);
    forceColour(contact.force_n ?? 0, this.material.color);
    this.trailMaterial.color.copy(this.material.color);
    this.trailDotMaterial.color.copy(this.material.color);
    if (trackChanged) this.labelEl.textContent = `#${contact.track_id}`;
    this.sphere.visible = true;
    this.trail.visible = true;
    this.updateShear(contact);

    // Append to the trail (base frame, metres), dropping the oldest point when it is full.
    if (this.trailCount === TRAIL_POINTS) {
      this.trailPositions.copyWithin(0, 3);
      this.trailCount--;
    }
    this.trailPositions.set([x * MM, y * MM, z * MM], 3 * this.trailCount);
    this.trailCount++;
    this.trailGeometry.attributes.position.needsUpdate = true;
    this.trailGeometry.setDrawRange(0, this.trailCount);
  }

  setTrailOpacity(opacity) {
    this.trailMaterial.opacity = opacity;
    this.trailDotMaterial.opacity = opacity;
  }

  // The shear arrow: from the sphere's surface along the force, SHEAR_MM_PER_N long per newton.
  updateShear(contact) {
    const s = contact.shear_n;
    const newtons = s ? Math.hypot(s[0], s[1], s[2]) : 0;
    const shown = (contact.flags ?? []).includes('shear') && newtons > 0;
    this.arrow.visible = shown;
    if (!shown) return;
    const dir = new THREE.Vector3(s[0], s[1], s[2]).divideScalar(newtons);
    const radius = contactRadiusMm(contact.depth_mm ?? 0);
    this.arrow.position.copy(this.sphere.position).addScaledVector(dir, radius * MM);
    this.arrow.setDirection(dir);
    const length = Math.max(newtons * SHEAR_MM_PER_N, 4) * MM;
    this.arrow.setLength(length, Math.min(6 * MM, 0.4 * length), Math.min(4 * MM, 0.3 * length));
  }

  // The arrow's direction in the base frame read back from its world transform (null: hidden).
  shearArrowBase() {
    if (!this.arrow.visible) return null;
    const tip = this.arrow.localToWorld(new THREE.Vector3(0, 1, 0));
    const tail = this.arrow.localToWorld(new THREE.Vector3(0, 0, 0));
    base.worldToLocal(tip);
    base.worldToLocal(tail);
    return [tip.x - tail.x, tip.y - tail.y, tip.z - tail.z];
  }

  end(nowMs) {
    this.sphere.visible = false;
    this.arrow.visible = false;
    this.endedMs = nowMs;
  }

  // Base-frame position (mm) read back from the sphere's world transform.
  positionBaseMm() {
    const p = this.sphere.getWorldPosition(new THREE.Vector3());
    base.worldToLocal(p);
    return [p.x / MM, p.y / MM, p.z / MM];
  }
}

function forceColour(forceN, target) {
  const t = Math.min(Math.max(forceN / FORCE_MAX_N, 0), 1) * (FORCE_STOPS.length - 1);
  const i = Math.min(Math.floor(t), FORCE_STOPS.length - 2);
  return target.lerpColors(FORCE_STOPS[i], FORCE_STOPS[i + 1], t - i);
}

function updateContacts(msg) {
  const now = performance.now();
  const seen = new Set();
  for (const contact of msg.contacts ?? []) {
    if (!Array.isArray(contact.position_mm)) continue;
    seen.add(contact.track_id);
    let view = contactViews.get(contact.track_id);
    if (!view) {
      view = freeViews.pop() ?? new ContactView();
      view.reset();
      contactViews.set(contact.track_id, view);
    }
    view.update(contact, msg.stamp_us);
  }
  for (const [trackId, view] of contactViews) {
    if (seen.has(trackId)) continue;
    contactViews.delete(trackId);
    view.end(now);
    fadingViews.add(view);
    if (selection?.contact === view) selectionMarker.removeFromParent();
  }
  if (selection?.contact) markDetailsDirty();
  if (contactRecording) recordContacts();
}

// For tests (window.skinbusView.record()): the contacts the scene holds after each contacts
// message, so that a reader polling the page under load still sees every instant.
let contactRecording = null;   // { snapshots: [[contact summary]], max, dropped } or null

// A vector's components rounded to 0.001 (mm) for summaries.
const round = (v) => v.map((x) => Math.round(x * 1000) / 1000);

function contactSummaries() {
  return [...contactViews.values()].map((v) => ({
    track_id: v.data.track_id,
    node: v.data.node,
    stamp_us: v.stampUs,
    depth_mm: v.data.depth_mm,
    u_mm: v.data.u_mm,
    v_mm: v.data.v_mm,
    position_base_mm: round(v.positionBaseMm()),
    shear_n: v.data.shear_n ?? null,
    flags: v.data.flags ?? [],
    shear_arrow_base: v.shearArrowBase(),
  }));
}

function recordContacts() {
  const r = contactRecording;
  contactsGroup.updateWorldMatrix(true, true);  // the spheres and arrows as the next frame draws them
  if (r.snapshots.length >= r.max) {
    r.snapshots.shift();
    r.dropped++;
  }
  r.snapshots.push(contactSummaries());
}

function fadeTrails(now) {
  for (const view of fadingViews) {
    const t = (now - view.endedMs) / TRAIL_FADE_MS;
    if (t < 1) {
      view.setTrailOpacity(0.9 * (1 - t));
      continue;
    }
    fadingViews.delete(view);
    view.reset();
    freeViews.push(view);
  }
}

// -- the sensors' fields (skinbus-view -i / --candump) ---------------------------------------------

// The latest `fields` message per node: the 16 sensors' field change, tared on the patch, uT,
// sensor-major x,y,z in each chip's axes; sent while a patch is pressed (docs/view.md).
const fieldsByNode = new Map();

// Commands to a patch (skinbus-view --allow-commands; the page is read-only otherwise).
const commandResults = [];   // the latest command_result messages, newest first

function sendCommand(node, command, mode) {
  if (stream.readOnly !== false || !stream.socketOpen) return false;
  stream.socket.send(JSON.stringify({ type: 'command', node, command, ...(mode ? { mode } : {}) }));
  return true;
}

function commandPanel(node) {
  const wrap = document.createElement('div');
  wrap.id = 'commands';
  for (const [label, command, mode] of [['tare', 'tare'], ['stream', 'mode', 'stream'],
    ['event', 'mode', 'event'], ['off', 'mode', 'off']]) {
    const button = document.createElement('button');
    button.textContent = label;
    button.title = mode ? `set the patch's mode to ${mode}` : 'capture a new baseline';
    button.addEventListener('click', () => sendCommand(node, command, mode));
    wrap.append(button);
  }
  const last = commandResults.find((r) => r.node === node);
  if (last) {
    const note = document.createElement('p');
    note.className = 'hint';
    note.textContent = `${last.command}: ${last.ok ? 'ok' : 'refused'} (${last.detail})`;
    wrap.append(note);
  }
  return wrap;
}
const SENSOR_GRID = 4;            // sensors per row (index = row * 4 + column, from -u,-v)
const FIELD_SCALE_UT = 50;        // the heat map's full scale
const SENSOR_CELL_PX = 44;

function updateFields(msg) {
  if (!Number.isInteger(msg.node) || !Array.isArray(msg.field_ut)) return;
  let maxUt = 0;
  for (const x of msg.field_ut) if (Number.isFinite(x)) maxUt = Math.max(maxUt, Math.abs(x));
  fieldsByNode.set(msg.node, { ...msg, max_ut: maxUt });
  if (selection?.patch?.spec.node === msg.node) markDetailsDirty();
}

// A 4 x 4 heat map of |dB| with the in-plane (x, y) change as arrows, for the details panel.
function sensorPanel(node) {
  const fields = fieldsByNode.get(node);
  const wrap = document.createElement('div');
  wrap.id = 'sensors';
  const title = document.createElement('h3');
  title.textContent = 'sensors: field change (uT)';
  wrap.append(title);
  if (!fields) {
    const hint = document.createElement('p');
    hint.className = 'hint';
    hint.textContent = messageCounts.fields ? 'not pressed since the page opened'
      : 'no bus data (skinbus-view -i IFACE or --candump shows them)';
    wrap.append(hint);
    return wrap;
  }
  const sensors = fields.field_ut.length / 3;
  const rows = Math.ceil(sensors / SENSOR_GRID);
  const canvas = document.createElement('canvas');
  canvas.id = 'sensor-grid';
  canvas.width = SENSOR_GRID * SENSOR_CELL_PX;
  canvas.height = rows * SENSOR_CELL_PX;
  canvas.dataset.maxUt = fields.max_ut.toFixed(1);
  const g = canvas.getContext('2d');
  const colour = new THREE.Color();
  for (let s = 0; s < sensors; ++s) {
    const [bx, by, bz] = fields.field_ut.slice(3 * s, 3 * s + 3);
    const x0 = (s % SENSOR_GRID) * SENSOR_CELL_PX;
    const y0 = (rows - 1 - Math.floor(s / SENSOR_GRID)) * SENSOR_CELL_PX;   // +v up
    if (![bx, by, bz].every(Number.isFinite)) {
      g.fillStyle = '#444a50';   // faulty sensor
      g.fillRect(x0 + 1, y0 + 1, SENSOR_CELL_PX - 2, SENSOR_CELL_PX - 2);
      continue;
    }
    forceColour(Math.hypot(bx, by, bz) / FIELD_SCALE_UT * FORCE_MAX_N, colour);
    g.fillStyle = `#${colour.getHexString()}`;
    g.fillRect(x0 + 1, y0 + 1, SENSOR_CELL_PX - 2, SENSOR_CELL_PX - 2);
    const len = Math.min(1, Math.hypot(bx, by) / FIELD_SCALE_UT) * SENSOR_CELL_PX * 0.45;
    const angle = Math.atan2(-by, bx);   // canvas y points down
    const cx = x0 + SENSOR_CELL_PX / 2, cy = y0 + SENSOR_CELL_PX / 2;
    g.strokeStyle = '#101418';
    g.lineWidth = 2;
    g.beginPath();
    g.moveTo(cx, cy);
    g.lineTo(cx + len * Math.cos(angle), cy + len * Math.sin(angle));
    g.stroke();
  }
  wrap.append(canvas);
  const note = document.createElement('p');
  note.className = 'hint';
  note.textContent = `max ${fields.max_ut.toFixed(1)} uT; colour |dB| (0-${FIELD_SCALE_UT} uT), ` +
    'arrow the in-plane change (chip axes)' + (fields.saturated?.length ? `; saturated: ${fields.saturated.join(', ')}` : '');
  wrap.append(note);
  return wrap;
}

// -- selection (click a patch or a contact) ------------------------------------------------------

// {patch: PatchView} or {contact: ContactView, trackId, stampUs, data}: a contact's latest data
// is kept, for its view goes to another track once this one has ended.
let selection = null;
let detailsDirty = false;
let detailsShownMs = 0;
const detailsEl = document.getElementById('details');

function markDetailsDirty() { detailsDirty = true; }

function select(next) {
  selection?.patch?.setSelected(false);
  selectionMarker.removeFromParent();
  selection = next;
  selection?.patch?.setSelected(true);
  if (selection?.contact) selection.contact.sphere.add(selectionMarker);
  for (const row of patchRows.values()) {
    row.tr.classList.toggle('selected', row.view !== null && row.view === selection?.patch);
  }
  detailsDirty = true;
  refreshDetails(performance.now(), true);
}

const raycaster = new THREE.Raycaster();
const pointerDown = new THREE.Vector2();

renderer.domElement.addEventListener('pointerdown', (e) => pointerDown.set(e.clientX, e.clientY));
renderer.domElement.addEventListener('pointerup', (e) => {
  if (Math.hypot(e.clientX - pointerDown.x, e.clientY - pointerDown.y) > 4) return;  // a drag
  const rect = renderer.domElement.getBoundingClientRect();
  const ndc = new THREE.Vector2(
    ((e.clientX - rect.left) / rect.width) * 2 - 1,
    -((e.clientY - rect.top) / rect.height) * 2 + 1);
  raycaster.setFromCamera(ndc, camera);
  const targets = patchViews.filter((v) => v.mesh).map((v) => v.mesh);
  for (const view of contactViews.values()) targets.push(view.sphere);
  const hit = raycaster.intersectObjects(targets, false)[0];
  if (!hit) select(null);
  else if (hit.object.userData.contact) {
    const view = hit.object.userData.contact;
    select({ contact: view, trackId: view.data.track_id, stampUs: view.stampUs, data: view.data });
  } else select({ patch: hit.object.userData.patch });
});

// Key/value rows of an object; numbers short, arrays joined.
function formatValue(value) {
  if (typeof value === 'number') return Number.isInteger(value) ? String(value) : value.toFixed(3);
  if (Array.isArray(value)) return value.map(formatValue).join(', ');
  if (value && typeof value === 'object') return JSON.stringify(value);
  return String(value);
}

function detailsTable(title, entries) {
  const fragment = document.createDocumentFragment();
  const h = document.createElement('p');
  h.textContent = title;
  fragment.append(h);
  const table = document.createElement('table');
  for (const [key, value] of entries) {
    const tr = table.insertRow();
    tr.insertCell().textContent = key;
    tr.insertCell().textContent = formatValue(value);
  }
  fragment.append(table);
  return fragment;
}

function refreshDetails(now, force = false) {
  if (!detailsDirty || (!force && now - detailsShownMs < DETAILS_PERIOD_MS)) return;
  detailsDirty = false;
  detailsShownMs = now;
  detailsEl.replaceChildren();
  if (selection?.patch) {
    const { spec, status } = selection.patch;
    const geometry = Object.entries(spec).filter(([key]) => key !== 'grid' && key !== 'node');
    if (stream.readOnly === false) detailsEl.append(commandPanel(spec.node));
    detailsEl.append(sensorPanel(spec.node));
    detailsEl.append(detailsTable(`patch ${spec.node} (${selection.patch.state})`, [
      ...geometry,
      ['grid', spec.grid ? `${spec.grid.nu} x ${spec.grid.nv}` : '-'],
    ]));
    if (status) detailsEl.append(detailsTable('status', Object.entries(status)));
  } else if (selection?.contact) {
    const view = selection.contact;
    const live = contactViews.get(selection.trackId) === view;
    if (live) {
      selection.stampUs = view.stampUs;
      selection.data = view.data;
    }
    detailsEl.append(detailsTable(`contact #${selection.trackId}${live ? '' : ' (ended)'}`,
      [['stamp_us', selection.stampUs], ...Object.entries(selection.data)]));
  } else {
    const hint = document.createElement('p');
    hint.className = 'hint';
    hint.textContent = 'click a patch or a contact in the scene';
    detailsEl.append(hint);
  }
}

// -- patch table and events ----------------------------------------------------------------------

const patchBody = document.querySelector('#patches tbody');
const patchesEmpty = document.getElementById('patches-empty');
const patchRows = new Map();   // "interface/node" -> {tr, cells, view}
const PATCH_COLUMNS = ['node', 'link', 'state', 'samples', 'samples_lost', 'reboots'];

function updatePatchStatus(msg) {
  const present = new Set();
  for (const status of msg.patches ?? []) {
    const key = `${status.interface}/${status.node}`;
    present.add(key);
    const view = patchViewFor(status);
    view?.setStatus(status);
    let row = patchRows.get(key);
    if (!row) {
      const tr = document.createElement('tr');
      const cells = PATCH_COLUMNS.map(() => tr.insertCell());
      row = { tr, cells, node: status.node, view: null };
      tr.addEventListener('click', () => row.view && select({ patch: row.view }));
      // Rows in node order.
      const after = [...patchRows.values()].find((r) => r.node > status.node);
      patchBody.insertBefore(tr, after?.tr ?? null);
      patchRows.set(key, row);
    }
    row.view = view;
    PATCH_COLUMNS.forEach((column, i) => {
      const text = String(status[column] ?? '-');
      if (row.cells[i].textContent !== text) {
        row.cells[i].textContent = text;
        row.cells[i].title = text;
      }
    });
    row.cells[2].style.color = STATE_COLOURS[status.state] ?? '';
  }
  for (const [key, row] of patchRows) {
    if (present.has(key)) continue;
    row.tr.remove();
    patchRows.delete(key);
  }
  patchesEmpty.hidden = patchRows.size > 0;
  for (const event of msg.events ?? []) addEvent(event);
  if (selection?.patch) markDetailsDirty();
}

// Events by how bad they are (docs/aggregator.md lists them); others are plain.
const EVENT_CLASSES = {
  online: 'good', returned: 'good', interface_up: 'good', kinematics_fresh: 'good',
  host_caught_up: 'good',
  degraded: 'warn', stale: 'warn', rebooted: 'warn', sequence_gap: 'warn', bad_frames: 'warn',
  kinematics_stale: 'warn', host_lagging: 'warn',
  offline: 'bad', duplicate_id: 'bad', unknown_patch: 'bad', no_model: 'bad',
  interface_down: 'bad',
};

const eventsEl = document.getElementById('events');
const eventKeys = new Map();   // listed event's key -> its <li>, to skip an event sent twice

function addEvent(event) {
  const key = `${event.time_us}|${event.event}|${event.node}|${event.detail}`;
  if (eventKeys.has(key)) return;
  const li = document.createElement('li');
  const time = document.createElement('time');
  time.textContent = Number.isFinite(event.time_us)
    ? new Date(event.time_us / 1000).toISOString().slice(11, 23) : '-';
  const name = document.createElement('span');
  name.className = `event ${EVENT_CLASSES[event.event] ?? ''}`;
  name.textContent = event.event;
  const detail = document.createElement('span');
  detail.className = 'detail';
  detail.textContent = `node ${event.node}: ${event.detail ?? ''}`;
  li.append(time, name, detail);
  eventsEl.prepend(li);
  eventKeys.set(key, li);
  while (eventKeys.size > MAX_EVENTS) {
    const [oldest, oldestLi] = eventKeys.entries().next().value;
    oldestLi.remove();
    eventKeys.delete(oldest);
  }
}

// -- the stream ----------------------------------------------------------------------------------

const messageCounts = {};        // type -> messages handled
const handlingMs = {};           // type -> main-thread ms spent handling them (parsing excluded)
const stream = {
  live: true,
  socket: null,                    // the live WebSocket
  socketOpen: false,
  readOnly: true,                  // until the server's hello says otherwise
  lastFreshMs: performance.now(),  // when the host last showed signs of life
  hostAgeMs: null,                 // the latest heartbeat's host_age_ms, null once superseded
  replay: null,                    // {position, total, ended} in replay mode
};

function handleMessage(type, msg) {
  switch (type) {
    case 'joint_state':
      applyJointState(msg);
      break;
    case 'contacts':
      updateContacts(msg);
      markFresh();
      break;
    case 'patch_status':
      updatePatchStatus(msg);
      markFresh();
      break;
    case 'fields':
      updateFields(msg);
      break;
    case 'hello':
      stream.readOnly = msg.read_only !== false;
      markDetailsDirty();
      break;
    case 'command_result':
      commandResults.unshift(msg);
      commandResults.length = Math.min(commandResults.length, 10);
      markDetailsDirty();
      break;
    case 'heartbeat':
      // host_age_ms: how long ago the server last heard the host (-1: never).
      stream.hostAgeMs = Number.isFinite(msg.host_age_ms) ? msg.host_age_ms : null;
      if (msg.host_age_ms >= 0 && msg.host_age_ms <= STALL_MS) stream.lastFreshMs = performance.now();
      break;
    default:
      break;   // hello, and anything newer than this page: counted only
  }
}

function markFresh() {
  stream.lastFreshMs = performance.now();
  stream.hostAgeMs = null;
}

// Handles one message, counted and timed by its type (performance.now() around the handler: the
// DOM and scene updates it makes, not the layout or rendering they cause later in the frame).
function handleMessageSafely(msg) {
  const type = typeof msg?.type === 'string' ? msg.type : '(none)';
  const startMs = performance.now();
  try {
    handleMessage(type, msg);
  } catch (e) {
    recordError(`${type}: ${e.message}`);
  }
  messageCounts[type] = (messageCounts[type] ?? 0) + 1;
  handlingMs[type] = (handlingMs[type] ?? 0) + performance.now() - startMs;
}

function connect() {
  const url = `${location.protocol === 'https:' ? 'wss' : 'ws'}://${location.host}/ws`;
  const socket = new WebSocket(url);
  stream.socket = socket;
  socket.onopen = () => { stream.socketOpen = true; };
  socket.onmessage = (e) => {
    let msg;
    try {
      msg = JSON.parse(e.data);
    } catch (err) {
      recordError(`stream: ${err.message}`);
      return;
    }
    handleMessageSafely(msg);
  };
  socket.onclose = () => {
    stream.socketOpen = false;
    setTimeout(connect, RECONNECT_MS);
  };
}

// Plays a JSON-lines file at the pace of its stamps (see the top of this file).
async function replay(url, speed) {
  const response = await fetch(url);
  if (!response.ok) throw new Error(`replay ${url}: HTTP ${response.status}`);
  const messages = [];
  (await response.text()).split('\n').forEach((line, i) => {
    if (!line.trim()) return;
    try {
      messages.push(JSON.parse(line));
    } catch (e) {
      recordError(`replay ${url} line ${i + 1}: ${e.message}`);
    }
  });
  const state = { position: 0, total: messages.length, ended: false };
  stream.replay = state;
  const firstStamp = messages.find((m) => Number.isFinite(m.stamp_us))?.stamp_us ?? 0;
  const startMs = performance.now();
  let dueMs = 0;   // replay time of the next message; never goes back (file order wins)
  const step = () => {
    const elapsedMs = performance.now() - startMs;
    while (state.position < messages.length) {
      const msg = messages[state.position];
      if (Number.isFinite(msg.stamp_us)) {
        dueMs = Math.max(dueMs, (msg.stamp_us - firstStamp) / 1000 / speed);
      }
      if (dueMs > elapsedMs) break;
      handleMessageSafely(msg);
      state.position++;
    }
    if (state.position < messages.length) setTimeout(step, dueMs - elapsedMs);
    else state.ended = true;
  };
  step();
}

// Why the stream counts as stalled now, or null.
function stallReason(now) {
  if (stream.live && !stream.socketOpen) return 'stream stalled: no connection to skinbus-view, reconnecting';
  if (stream.hostAgeMs !== null && stream.hostAgeMs < 0) return 'stream stalled: nothing from the host yet';
  if (stream.hostAgeMs !== null && stream.hostAgeMs > STALL_MS) {
    return `stream stalled: nothing from the host for ${(stream.hostAgeMs / 1000).toFixed(1)} s`;
  }
  if (now - stream.lastFreshMs > STALL_MS) {
    const ended = stream.replay?.ended ? ' (the replay has ended)' : '';
    return `stream stalled: nothing for ${((now - stream.lastFreshMs) / 1000).toFixed(0)} s${ended}`;
  }
  return null;
}

const bannerEl = document.getElementById('banner');

function updateBanner(now) {
  const reason = stallReason(now);
  bannerEl.hidden = reason === null;
  if (reason !== null && bannerEl.textContent !== reason) bannerEl.textContent = reason;
}

// -- legend --------------------------------------------------------------------------------------

function buildLegend() {
  const stops = FORCE_STOPS.map((c, i) =>
    `#${c.getHexString()} ${(100 * i / (FORCE_STOPS.length - 1)).toFixed(1)}%`);
  document.getElementById('force-ramp').style.background = `linear-gradient(to right, ${stops.join(', ')})`;
  const ticks = document.getElementById('force-ticks');
  for (let f = 0; f <= FORCE_MAX_N; f += FORCE_MAX_N / 4) {
    const tick = document.createElement('span');
    tick.textContent = f === FORCE_MAX_N ? `${f}+` : String(f);
    ticks.append(tick);
  }
  const keys = document.getElementById('state-keys');
  for (const [state, colour] of Object.entries(STATE_COLOURS)) {
    const key = document.createElement('span');
    const swatch = document.createElement('span');
    swatch.className = 'swatch';
    swatch.style.background = colour;
    key.append(swatch, state === 'unknown' ? 'no status' : state);
    keys.append(key);
  }
}

// -- render loop ---------------------------------------------------------------------------------

const fpsEl = document.getElementById('fps');
const fpsMeter = { frames: 0, sinceMs: performance.now(), fps: 0 };

function frame(now) {
  requestAnimationFrame(frame);
  fadeTrails(now);
  updateBanner(now);
  refreshDetails(now);
  controls.update();
  renderer.render(scene3d, camera);
  labelRenderer.render(scene3d, camera);

  fpsMeter.frames++;
  if (now - fpsMeter.sinceMs >= 1000) {
    fpsMeter.fps = (1000 * fpsMeter.frames) / (now - fpsMeter.sinceMs);
    fpsMeter.frames = 0;
    fpsMeter.sinceMs = now;
    fpsEl.textContent = `${fpsMeter.fps.toFixed(0)} fps${software ? ' (software rendering)' : ''}`;
  }
}

// -- for tests -----------------------------------------------------------------------------------

window.skinbusView = {
  // Sends a command to patch `node` as its buttons do ('tare', or 'mode' with 'stream', 'event'
  // or 'off'); false when the page is read-only or not connected. The answer arrives as a
  // command_result (summary().command_results).
  command(node, command, mode) {
    return sendCommand(node, command, mode);
  },
  // Selects patch `node` as a click would and returns what its sensor panel shows: the heat
  // map's largest field change (uT), or null when the panel has no grid.
  selectPatch(node) {
    const view = patchViews.find((v) => v.spec.node === node);
    if (!view) return null;
    select({ patch: view });
    markDetailsDirty();
    refreshDetails(performance.now(), true);
    const grid = document.getElementById('sensor-grid');
    return grid ? Number(grid.dataset.maxUt) : null;
  },
  // Starts keeping what the scene holds after every contacts message (at most maxSnapshots, the
  // oldest dropped first): takeRecorded() returns them.
  record(maxSnapshots) {
    contactRecording = { snapshots: [], max: Math.max(1, maxSnapshots), dropped: 0 };
  },
  // The contacts of every contacts message since the last call, each as summary().contacts reads
  // them, and how many were dropped to the bound; null when not recording.
  takeRecorded() {
    if (!contactRecording) return null;
    const { snapshots, dropped } = contactRecording;
    contactRecording.snapshots = [];
    contactRecording.dropped = 0;
    return { snapshots, dropped };
  },
  // What the page shows, read back from its scene graph: patch centres through the page's own
  // link transforms and contact positions from the spheres' world positions, both in the base
  // frame in mm.
  summary() {
    zUp.updateMatrixWorld(true);
    return {
      robot_loaded: robot !== null,
      links: robot ? Object.keys(robot.links).length : 0,
      joints: { ...jointsApplied },
      patches: patchViews.map((v) => ({
        node: v.spec.node,
        link: v.spec.link,
        state: v.state,
        drawn: v.mesh !== null,
        centre_base_mm: v.mesh ? round(v.centreBaseMm()) : null,
      })),
      contacts: contactSummaries(),
      read_only: stream.readOnly !== false,
      command_results: commandResults.map((r) => ({ ...r })),
      // node -> the largest field change (uT) of its latest `fields` message
      fields: Object.fromEntries([...fieldsByNode].map(([node, f]) => [node, f.max_ut])),
      messages: { ...messageCounts },
      handling_ms: { ...handlingMs },
      stalled: stallReason(performance.now()) !== null,
      fps: Math.round(fpsMeter.fps * 10) / 10,
      software_rendering: software,
      errors: [...errors],
      replay: stream.replay ? { ...stream.replay } : null,
    };
  },
};

// -- start ---------------------------------------------------------------------------------------

async function start() {
  const params = new URLSearchParams(location.search);
  const replayUrl = params.get('replay');
  const speedParam = Number(params.get('speed') ?? 1);
  const speed = speedParam > 0 ? speedParam : 1;
  stream.live = !replayUrl;
  document.getElementById('mode').textContent = replayUrl ? `replay ${replayUrl} x${speed}` : 'live';

  let scene = { patches: [] };
  const sceneUrl = params.get('scene') ?? '/api/scene';
  try {
    const response = await fetch(sceneUrl);
    if (!response.ok) throw new Error(`HTTP ${response.status}`);
    scene = await response.json();
  } catch (e) {
    recordError(`scene ${sceneUrl}: ${e.message}`);
  }

  if (scene.robot_url) {
    try {
      await loadRobot(scene.robot_url);
    } catch (e) {
      recordError(`robot ${scene.robot_url}: ${e.message}`);
    }
  }
  for (const spec of scene.patches ?? []) patchViews.push(new PatchView(spec));
  frameCamera();

  if (replayUrl) {
    await replay(replayUrl, speed);
  } else {
    connect();
  }
}

buildLegend();
requestAnimationFrame(frame);
start().catch((e) => recordError(e.message));
