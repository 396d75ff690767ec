// skinbus-view's Foxglove WebSocket server read by an independent implementation of the protocol:
// the FoxgloveClient of @foxglove/ws-protocol (npm, pinned in package-lock.json) over the `ws`
// package. Run by tests/e2e/view_foxglove_e2e.sh:
//
//   node tests/interop/foxglove_check.mjs --url ws://127.0.0.1:PORT --host-jsonl host.jsonl \
//     --map map.yaml --urdf robot.urdf --joints joints.csv --ready ready --done done
//
// Connects (subprotocol foxglove.websocket.v1), checks serverInfo and the advertised channels and
// schemas, subscribes to every channel, writes the file --ready once it has the first transforms
// and patches, and collects messages until the file --done exists. Then it checks the values
// against what it reads itself (not through skinbus code):
// - /skin/contacts: every contact publication skinbus-host wrote (--host-jsonl, its --json lines)
//   arrives, in order, with the host's stamp as the message time (at most the first 10 % may be
//   missing: published before DDS discovery matched skinbus-view; none after the first arrived), one sphere entity per contact, the same
//   track IDs, positions within 1e-6 m of the host's (mm / 1000), the sphere sized by depth, and a
//   deletion for every track that ended; at the end no contact is left;
// - /skin/contacts patch markers: one entity per patch of the skin map (--map, YAML read here),
//   on its link, with the surface points the map's pose and geometry give (1e-9 m), and in the
//   state the last /skin/patch_status gave that node;
// - /tf: every link of the URDF (--urdf, XML read here) from its parent, translation and
//   rotation within 1e-9 of the URDF's joint origin and axis at the joint positions of the
//   trajectory's last row (--joints, CSV);
// - all together: every contact, carried into its patch's frame through the /tf chain and the
//   map's pose, lies on that patch's surface (0.01 mm).
// Prints PASS/FAIL lines; exits 1 on any failure. FOXGLOVE_DUMP=FILE also writes every message
// received there (JSON lines: topic, timeNs, msg), to look at when a check fails.
import fs from "node:fs";
import wsProtocol from "@foxglove/ws-protocol"; // CommonJS: its exports through the default
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol;

// -- arguments ------------------------------------------------------------------------------------
const args = {};
for (let i = 2; i < process.argv.length; i += 2) args[process.argv[i].replace(/^--/, "")] = process.argv[i + 1];
for (const k of ["url", "host-jsonl", "map", "urdf", "joints", "ready", "done"]) {
  if (!args[k]) {
    console.error(`usage: foxglove_check.mjs --${k} ... (see the file's head)`);
    process.exit(2);
  }
}
const timeoutS = Number(args.timeout ?? 90);

let failures = 0;
function check(what, ok, detail = "") {
  console.log(`${ok ? "PASS" : "FAIL"} ${what}${detail ? ": " + detail : ""}`);
  if (!ok) failures += 1;
  return ok;
}

// -- small geometry (quaternions x, y, z, w; metres) ------------------------------------------------
const qmul = (a, b) => ({
  w: a.w * b.w - a.x * b.x - a.y * b.y - a.z * b.z,
  x: a.w * b.x + a.x * b.w + a.y * b.z - a.z * b.y,
  y: a.w * b.y - a.x * b.z + a.y * b.w + a.z * b.x,
  z: a.w * b.z + a.x * b.y - a.y * b.x + a.z * b.w,
});
const qconj = (q) => ({ x: -q.x, y: -q.y, z: -q.z, w: q.w });
const qaxis = (ax, angle) => {
  const n = Math.hypot(ax[0], ax[1], ax[2]);
  const s = Math.sin(angle / 2) / n;
  return { x: ax[0] * s, y: ax[1] * s, z: ax[2] * s, w: Math.cos(angle / 2) };
};
const qrpy = (r, p, y) => qmul(qaxis([0, 0, 1], y), qmul(qaxis([0, 1, 0], p), qaxis([1, 0, 0], r)));
const rotate = (q, v) => {
  const r = qmul(qmul(q, { x: v[0], y: v[1], z: v[2], w: 0 }), qconj(q));
  return [r.x, r.y, r.z];
};
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const dist = (a, b) => Math.hypot(a[0] - b[0], a[1] - b[1], a[2] - b[2]);
const xyz = (v) => [v.x, v.y, v.z];
// A transform {t, q} maps child points into the parent: p = q * c * q^-1 + t.
const compose = (a, b) => ({ t: add(a.t, rotate(a.q, b.t)), q: qmul(a.q, b.q) });
const inverse = (a) => {
  const qi = qconj(a.q);
  return { t: rotate(qi, a.t).map((x) => -x), q: qi };
};
const apply = (a, p) => add(rotate(a.q, p), a.t);
const sameRotation = (a, b) => 1 - Math.abs(a.x * b.x + a.y * b.y + a.z * b.z + a.w * b.w) < 1e-12;

// -- the inputs, read here -------------------------------------------------------------------------
function readUrdf(path) {
  const xml = fs.readFileSync(path, "utf8").replace(/<!--[\s\S]*?-->/g, "");
  const links = [...xml.matchAll(/<link\s+name="([^"]+)"/g)].map((m) => m[1]);
  const joints = [];
  for (const m of xml.matchAll(/<joint\s+([^>]*)>([\s\S]*?)<\/joint>/g)) {
    const attr = (s, name) => (s.match(new RegExp(`${name}="([^"]*)"`)) ?? [])[1];
    const body = m[2];
    const nums = (s, d) => (s == null ? d : s.trim().split(/\s+/).map(Number));
    const origin = body.match(/<origin\s+([^>]*)\/?>/);
    const axis = body.match(/<axis\s+([^>]*)\/?>/);
    joints.push({
      name: attr(m[1], "name"),
      type: attr(m[1], "type"),
      parent: attr(body.match(/<parent\s+([^>]*)>/)[1], "link"),
      child: attr(body.match(/<child\s+([^>]*)>/)[1], "link"),
      xyz: nums(origin && attr(origin[1], "xyz"), [0, 0, 0]),
      rpy: nums(origin && attr(origin[1], "rpy"), [0, 0, 0]),
      axis: nums(axis && attr(axis[1], "xyz"), [1, 0, 0]),
    });
  }
  return { links, joints };
}

function readLastJointRow(path) {
  const rows = fs.readFileSync(path, "utf8").trim().split("\n").filter((l) => !l.startsWith("#"));
  const names = rows[0].split(",").map((s) => s.trim());
  const last = rows[rows.length - 1].split(",").map(Number);
  const q = {};
  names.forEach((n, i) => {
    if (i > 0) q[n] = last[i];
  });
  return q;
}

function readSkinMap(path) {
  const text = fs.readFileSync(path, "utf8");
  const patches = [];
  for (const block of text.split(/\n\s*- node:/).slice(1)) {
    const get = (key) => (block.match(new RegExp(`\\n\\s*${key}:\\s*([^#\\n]*)`)) ?? [])[1]?.trim();
    const list = (s) => s.replace(/[[\]]/g, "").split(",").map(Number);
    const [w, x, y, z] = list(get("quaternion_wxyz"));
    patches.push({
      node: Number(block.trim().split(/\s/)[0]),
      link: get("link"),
      position_m: list(get("position_mm")).map((v) => v / 1000),
      q: { x, y, z, w },
      type: get("type"),
      size_m: list(get("size_mm")).map((v) => v / 1000),
      radius_m: Number(get("radius_mm") ?? 0) / 1000,
      axis: get("axis") ?? "v",
    });
  }
  return patches;
}

// -- collect -----------------------------------------------------------------------------------------
const channels = new Map(); // id -> channel
const topicOfSubscription = new Map();
const received = []; // {topic, timeNs, msg}
let serverInfo = null;
const statuses = [];

const ws = new WebSocket(args.url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
const client = new FoxgloveClient({ ws });
const decoder = new TextDecoder();
client.on("error", (e) => {
  console.log(`FAIL the connection: ${e?.message ?? e}`);
  process.exit(1);
});
client.on("serverInfo", (info) => {
  serverInfo = info;
});
client.on("status", (s) => statuses.push(s));
client.on("advertise", (list) => {
  for (const c of list) {
    channels.set(c.id, c);
    topicOfSubscription.set(client.subscribe(c.id), c.topic);
  }
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const topic = topicOfSubscription.get(subscriptionId) ?? `?${subscriptionId}`;
  received.push({ topic, timeNs: timestamp, msg: JSON.parse(decoder.decode(data)) });
});

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
const start = Date.now();
let ready = false;
while (!fs.existsSync(args.done)) {
  if (Date.now() - start > timeoutS * 1000) {
    check("the run ended in time", false, `no ${args.done} within ${timeoutS} s`);
    process.exit(1);
  }
  if (!ready && received.some((r) => r.topic === "/tf") && received.some((r) => r.topic === "/skin/contacts")) {
    fs.writeFileSync(args.ready, "ready\n");
    ready = true;
  }
  await sleep(20);
}
await sleep(500);
client.close();
if (process.env.FOXGLOVE_DUMP) fs.writeFileSync(process.env.FOXGLOVE_DUMP, received.map((r) => JSON.stringify({ topic: r.topic, timeNs: String(r.timeNs), msg: r.msg })).join("\n") + "\n");

// -- the protocol -------------------------------------------------------------------------------------
check("serverInfo received", serverInfo !== null && serverInfo.name === "skinbus-view",
  JSON.stringify(serverInfo));
check("no client operation refused", statuses.length === 0, JSON.stringify(statuses));
const expected = {
  "/skin/contacts": "foxglove.SceneUpdate",
  "/tf": "foxglove.FrameTransforms",
  "/skin/patch_status": "skinbus.PatchStatusArray",
};
for (const [topic, schemaName] of Object.entries(expected)) {
  const c = [...channels.values()].find((ch) => ch.topic === topic);
  let schema = null;
  try {
    schema = c && JSON.parse(c.schema);
  } catch {
    schema = null;
  }
  check(`channel ${topic} advertised as ${schemaName} (json, jsonschema)`,
    c !== undefined && c.schemaName === schemaName && c.encoding === "json" &&
      c.schemaEncoding === "jsonschema" && schema?.type === "object" && schema?.title === schemaName,
    c ? `${c.schemaName} ${c.encoding} ${c.schemaEncoding}` : "missing");
}
const byTopic = (t) => received.filter((r) => r.topic === t);
console.log(`received: ${["/skin/contacts", "/tf", "/skin/patch_status"].map((t) => `${t} ${byTopic(t).length}`).join(", ")}`);

// -- /tf against the URDF ----------------------------------------------------------------------------
const urdf = readUrdf(args.urdf);
const q = readLastJointRow(args.joints);
const tfs = byTopic("/tf");
const lastTf = tfs.length ? tfs[tfs.length - 1].msg.transforms : [];
const tfByChild = new Map(lastTf.map((t) => [t.child_frame_id, t]));
const root = urdf.links.find((l) => !urdf.joints.some((j) => j.child === l));
check("a transform for every link but the root", lastTf.length === urdf.links.length - 1 &&
  urdf.links.every((l) => l === root || tfByChild.has(l)), `${lastTf.length} of ${urdf.links.length - 1}`);
let tfWorst = 0, tfBad = [];
for (const j of urdf.joints) {
  const t = tfByChild.get(j.child);
  if (!t) continue;
  let want = { t: j.xyz, q: qrpy(...j.rpy) };
  const v = q[j.name] ?? 0;
  if (j.type === "revolute" || j.type === "continuous") want = compose(want, { t: [0, 0, 0], q: qaxis(j.axis, v) });
  if (j.type === "prismatic") want = compose(want, { t: j.axis.map((a) => (a * v) / 1000), q: qaxis([1, 0, 0], 0) });
  const e = dist(want.t, xyz(t.translation));
  tfWorst = Math.max(tfWorst, e);
  if (t.parent_frame_id !== j.parent || e > 1e-9 || !sameRotation(want.q, t.rotation)) tfBad.push(j.child);
}
check("every transform is the URDF's joint at the trajectory's pose (1e-9)", tfBad.length === 0,
  `worst translation error ${tfWorst.toExponential(2)} m; wrong: ${tfBad.join(", ") || "none"}`);
// Each link's pose in the root frame, from the /tf chain.
const linkPose = (link) => {
  let pose = { t: [0, 0, 0], q: { x: 0, y: 0, z: 0, w: 1 } };
  for (let l = link, n = 0; l !== root && n < 100; n++) {
    const t = tfByChild.get(l);
    if (!t) return null;
    pose = compose({ t: xyz(t.translation), q: t.rotation }, pose);
    l = t.parent_frame_id;
  }
  return pose;
};

// -- /skin/contacts: the contacts against the host's own output ---------------------------------------
const hostArrays = fs.readFileSync(args["host-jsonl"], "utf8").trim().split("\n")
  .map((l) => JSON.parse(l)).filter((j) => j.type === "contacts");
const scene = byTopic("/skin/contacts");
const contactUpdates = scene.filter((r) =>
  !r.msg.entities.some((e) => e.id.startsWith("patch/")));
// In order: the host publishes a stamp again when only a track ends, so stamps are not unique.
const updateOf = new Map(); // host array -> its update
for (let j = 0, i = 0; i < hostArrays.length; i++) {
  const t = BigInt(hostArrays[i].stamp_us) * 1000n;
  while (j < contactUpdates.length && contactUpdates[j].timeNs < t) j++;
  if (j < contactUpdates.length && contactUpdates[j].timeNs === t) updateOf.set(hostArrays[i], contactUpdates[j++].msg);
}
let matched = 0, leading = 0, worstPos = 0;
const problems = [];
let previous = new Set();
let sheared = 0;  // contacts whose shear arrow was checked
for (const h of hostArrays) {
  const u = updateOf.get(h);
  const now = new Set(h.contacts.map((c) => c.track_id));
  if (!u) {
    // Before skinbus-view's reader matched the host's writer (DDS discovery, volatile) a
    // publication may not reach it; after the first that did, every one must.
    if (matched > 0) problems.push(`no update stamped ${h.stamp_us}`);
    else leading += 1;
    previous = now;
    continue;
  }
  matched += 1;
  if (u.entities.length !== h.contacts.length) problems.push(`${h.stamp_us}: ${u.entities.length} entities, ${h.contacts.length} contacts`);
  for (const c of h.contacts) {
    const e = u.entities.find((x) => x.id === `contact/${c.track_id}`);
    if (!e || e.frame_id !== h.base_frame || e.spheres.length !== 1) {
      problems.push(`${h.stamp_us}: track ${c.track_id} missing or not one sphere in ${h.base_frame}`);
      continue;
    }
    const s = e.spheres[0];
    const err = dist(xyz(s.pose.position), c.position_mm.map((v) => v / 1000));
    worstPos = Math.max(worstPos, err);
    if (err > 1e-6) problems.push(`${h.stamp_us}: track ${c.track_id} ${err} m off`);
    const diameter = (2 * (5 + 3 * Math.min(Math.max(c.depth_mm, 0), 5))) / 1000;
    if (Math.abs(s.size.x - diameter) > 1e-9) problems.push(`${h.stamp_us}: track ${c.track_id} sphere ${s.size.x} m, depth ${c.depth_mm} mm`);
    // A contact with a shear force has one arrow along it (its pose's x axis), the others none.
    const newtons = Math.hypot(...c.shear_n);
    const wantArrow = c.flags.includes("shear") && newtons > 0;
    if (e.arrows.length !== (wantArrow ? 1 : 0)) {
      problems.push(`${h.stamp_us}: track ${c.track_id} has ${e.arrows.length} arrows`);
    } else if (wantArrow) {
      const o = e.arrows[0].pose.orientation;
      // The quaternion's rotation of (1, 0, 0).
      const x = [1 - 2 * (o.y * o.y + o.z * o.z), 2 * (o.x * o.y + o.w * o.z), 2 * (o.x * o.z - o.w * o.y)];
      const cos = x.reduce((acc, v, k) => acc + v * c.shear_n[k], 0) / newtons;
      if (!(cos > 1 - 1e-9)) problems.push(`${h.stamp_us}: track ${c.track_id} arrow off the shear (cos ${cos})`);
      sheared += 1;
    }
  }
  const after = BigInt(h.stamp_us) * 1000n + 1n; // deletions stamped just after the publication
  const deleted = new Set(u.deletions.filter((d) => d.type === 0 &&
    BigInt(d.timestamp.sec) * 1000000000n + BigInt(d.timestamp.nsec) === after).map((d) => d.id));
  for (const id of previous) {
    if (!now.has(id) && !deleted.has(`contact/${id}`)) problems.push(`${h.stamp_us}: ended track ${id} not deleted`);
  }
  previous = now;
}
const pressed = hostArrays.filter((h) => h.contacts.length > 0).length;
check("the host published contacts", pressed >= 10, `${hostArrays.length} publications, ${pressed} with contacts`);
check("every contact publication of the host arrived as a SceneUpdate with its contacts",
  matched + leading === hostArrays.length && leading <= hostArrays.length / 10 && problems.length === 0,
  `${matched} of ${hostArrays.length} (${leading} before DDS matched); ` +
    `worst position error ${worstPos.toExponential(2)} m` +
    (problems.length ? `; ${problems.slice(0, 5).join("; ")}` : ""));
check("contacts with a shear force drawn with an arrow along it", sheared >= 10,
  `${sheared} arrows checked against the host's shear`);
const lastHost = hostArrays[hostArrays.length - 1];
check("the last publication leaves no contact", lastHost && lastHost.contacts.length === 0 &&
  updateOf.get(lastHost)?.entities.length === 0);

// -- patch markers against the skin map, and their states --------------------------------------------
const patches = readSkinMap(args.map);
const patchUpdates = scene.filter((r) => r.msg.entities.some((e) => e.id.startsWith("patch/")));
const lastPatches = patchUpdates.length ? patchUpdates[patchUpdates.length - 1].msg.entities : [];
const statusMsgs = byTopic("/skin/patch_status");
const lastStatus = statusMsgs.length ? statusMsgs[statusMsgs.length - 1].msg : { patches: [] };
check("patch status received", statusMsgs.length > 0 && lastStatus.type === "patch_status",
  `${statusMsgs.length} messages, ${lastStatus.patches.length} patches in the last`);
const markerBad = [];
let markerWorst = 0;
for (const p of patches) {
  const e = lastPatches.find((x) => x.id === `patch/${p.node}`);
  if (!e || e.frame_id !== p.link || e.triangles.length !== 1) {
    markerBad.push(`${p.node}: no marker on ${p.link}`);
    continue;
  }
  const pts = e.triangles[0].points.map(xyz);
  // Points the map gives: the patch's edge midpoints 1.5 mm out of the skin (a flat patch's
  // corners), in the link frame.
  const [su, sv] = p.size_m;
  const lift = 0.0015;
  let want;
  if (p.type === "flat") {
    want = [[-su / 2, -sv / 2, lift], [su / 2, -sv / 2, lift], [-su / 2, sv / 2, lift], [su / 2, sv / 2, lift]];
  } else {
    const R = p.radius_m;
    const across = p.axis === "v" ? su : sv;
    const theta = across / 2 / R;
    const a = Math.sin(theta) * (R + lift), c = Math.cos(theta) * (R + lift) - R;
    want = p.axis === "v"
      ? [[0, -sv / 2, lift], [0, sv / 2, lift], [a, sv / 2, c], [-a, -sv / 2, c]]
      : [[-su / 2, 0, lift], [su / 2, 0, lift], [su / 2, a, c], [-su / 2, -a, c]];
  }
  for (const w of want) {
    const inLink = add(rotate(p.q, w), p.position_m);
    const nearest = Math.min(...pts.map((x) => dist(x, inLink)));
    markerWorst = Math.max(markerWorst, nearest);
    if (nearest > 1e-9) markerBad.push(`${p.node}: no point within 1e-9 m of ${inLink.map((v) => v.toFixed(4))}`);
  }
  const kv = Object.fromEntries(e.metadata.map((m) => [m.key, m.value]));
  const status = lastStatus.patches.find((s) => s.node === p.node);
  const state = status ? status.state : "unknown";
  if (kv.state !== state || kv.link !== p.link) markerBad.push(`${p.node}: state ${kv.state}, the status says ${state}`);
}
check(`a marker for every patch of the map (${patches.length}), on its link, where the map puts it, in its state`,
  patches.length > 0 && lastPatches.length === patches.length && markerBad.length === 0,
  `${lastPatches.length} markers; worst point ${markerWorst.toExponential(2)} m` +
    (markerBad.length ? `; ${markerBad.slice(0, 5).join("; ")}` : ""));
const online = lastPatches.filter((e) => e.metadata.some((m) => m.key === "state" && m.value === "online"));
check("the replayed patches are online", online.length >= 5, `${online.length} online`);

// -- together: every contact on its patch's surface through /tf and the map ---------------------------
let onSurface = 0, surfaceWorst = 0;
const offSurface = [];
for (const h of hostArrays) {
  for (const c of h.contacts) {
    const p = patches.find((x) => x.node === c.node);
    const lp = p && linkPose(p.link);
    if (!lp) {
      offSurface.push(`node ${c.node}: no patch or no transform chain`);
      continue;
    }
    const e = updateOf.get(h)?.entities.find((x) => x.id === `contact/${c.track_id}`);
    if (!e) continue;
    const inLink = apply(inverse(lp), xyz(e.spheres[0].pose.position));
    const inPatch = rotate(qconj(p.q), sub(inLink, p.position_m));
    const off = p.type === "flat" ? Math.abs(inPatch[2])
      : Math.abs(Math.hypot(p.axis === "v" ? inPatch[0] : inPatch[1], inPatch[2] + p.radius_m) - p.radius_m);
    surfaceWorst = Math.max(surfaceWorst, off);
    if (off > 1e-5) offSurface.push(`node ${c.node} track ${c.track_id}: ${(off * 1000).toFixed(3)} mm off`);
    onSurface += 1;
  }
}
check("every contact lies on its patch's surface through the /tf chain and the map (0.01 mm)",
  onSurface > 0 && offSurface.length === 0,
  `${onSurface} contacts; worst ${(surfaceWorst * 1000).toExponential(2)} mm` +
    (offSurface.length ? `; ${offSurface.slice(0, 5).join("; ")}` : ""));

console.log(failures === 0 ? "PASS the Foxglove client read everything right" : `FAIL ${failures} check(s)`);
process.exit(failures === 0 ? 0 : 1);
