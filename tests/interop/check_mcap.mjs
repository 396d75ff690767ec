// Reads a skinbus recording with independent implementations of MCAP (@mcap/core: the indexed
// reader, which checks the summary, chunk indexes and CRCs, and the streaming reader) and of ROS 2
// CDR (@foxglove/rosmsg parses each channel's ros2msg schema, @foxglove/rosmsg2-serialization
// decodes every message with it), and checks the values against what the host printed
// (skinbus-host --json --json-status, the same run).
//
//   node check_mcap.mjs RECORDING.mcap HOST.jsonl
//
// Exit status 0 when every check holds; 1 with the failures listed.
import { readFileSync } from "node:fs";
import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";

const [path, hostPath] = process.argv.slice(2);
if (!path || !hostPath) {
  console.error("usage: node check_mcap.mjs RECORDING.mcap HOST.jsonl");
  process.exit(2);
}
const failures = [];
const check = (ok, what) => {
  if (!ok) failures.push(what);
};
const near = (a, b, tol) => Math.abs(a - b) <= tol;

const bytes = new Uint8Array(readFileSync(path));
const readable = {
  size: async () => BigInt(bytes.length),
  read: async (offset, length) => bytes.subarray(Number(offset), Number(offset + length)),
};
const reader = await McapIndexedReader.Initialize({ readable });
check(reader.header.profile === "ros2", `profile ${reader.header.profile}, not ros2`);
const stats = reader.statistics;
check(stats !== undefined, "no Statistics record in the summary");

// One message reader per channel, from its schema alone.
const decoders = new Map();
const topics = new Map();
for (const [id, channel] of reader.channelsById) {
  const schema = reader.schemasById.get(channel.schemaId);
  check(schema.encoding === "ros2msg", `${channel.topic}: schema encoding ${schema.encoding}`);
  check(channel.messageEncoding === "cdr", `${channel.topic}: message encoding ${channel.messageEncoding}`);
  const text = new TextDecoder().decode(schema.data);
  decoders.set(id, new MessageReader(parse(text, { ros2: true })));
  topics.set(id, { topic: channel.topic, type: schema.name, messages: [] });
}

let indexed = 0;
for await (const m of reader.readMessages()) {
  const decoded = decoders.get(m.channelId).readMessage(m.data);
  topics.get(m.channelId).messages.push({ logTime: m.logTime, decoded });
  ++indexed;
}
check(BigInt(indexed) === stats.messageCount,
      `the indexed reader read ${indexed} messages, the statistics say ${stats.messageCount}`);

// The streaming reader reads the same file record by record (CRCs of every chunk checked).
const stream = new McapStreamReader({ validateCrcs: true });
stream.append(bytes);
let streamed = 0, attachments = [], metadata = [];
for (let r; (r = stream.nextRecord()); ) {
  if (r.type === "Message") ++streamed;
  if (r.type === "Attachment") attachments.push(r.name);
  if (r.type === "Metadata") metadata.push(r.name);
}
check(stream.done(), "the streaming reader did not reach the end magic");
check(streamed === indexed, `streamed ${streamed} messages, indexed ${indexed}`);

const byTopic = (t) => [...topics.values()].find((c) => c.topic === t);
const expectTypes = {
  "/skin/contacts": "skin_msgs/msg/ContactArray",
  "/skin/patch_status": "skin_msgs/msg/PatchStatusArray",
  "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
  "/skin/samples": "skin_msgs/msg/PatchSample",
  "/skin/can": "skin_msgs/msg/CanFrame",
  "/joint_states": "sensor_msgs/msg/JointState",
};
for (const [topic, type] of Object.entries(expectTypes)) {
  const c = byTopic(topic);
  check(c !== undefined, `no channel ${topic}`);
  if (c) check(c.type === type, `${topic}: type ${c.type}, not ${type}`);
}
check(attachments.length >= 2, `attachments: ${attachments}`);
check(metadata.includes("skinbus"), "no skinbus metadata record");

// The host's own output of the same run.
const lines = readFileSync(hostPath, "utf8").trim().split("\n").map((l) => JSON.parse(l));
const hostContacts = lines.filter((l) => l.type === "contacts");
const hostStatus = lines.filter((l) => l.type === "patch_status");
const toNs = (t) => BigInt(t.sec) * 1000000000n + BigInt(t.nanosec);
const usOf = (t) => Number(toNs(t) / 1000n);

const recContacts = byTopic("/skin/contacts")?.messages ?? [];
check(recContacts.length === hostContacts.length,
      `${recContacts.length} contact messages recorded, the host printed ${hostContacts.length}`);
let contactsCompared = 0;
for (let i = 0; i < Math.min(recContacts.length, hostContacts.length); ++i) {
  const r = recContacts[i].decoded, h = hostContacts[i];
  const where = `/skin/contacts[${i}]`;
  check(usOf(r.header.stamp) === h.stamp_us, `${where}: stamp ${usOf(r.header.stamp)} vs ${h.stamp_us}`);
  check(r.header.frame_id === h.base_frame, `${where}: frame_id ${r.header.frame_id}`);
  check(r.contacts.length === h.contacts.length, `${where}: ${r.contacts.length} contacts vs ${h.contacts.length}`);
  for (let k = 0; k < Math.min(r.contacts.length, h.contacts.length); ++k) {
    const a = r.contacts[k], b = h.contacts[k], w = `${where}.contacts[${k}]`;
    const p = [a.position.x, a.position.y, a.position.z];
    for (let j = 0; j < 3; ++j) check(near(p[j] * 1000, b.position_mm[j], 1e-9), `${w}.position ${p} vs ${b.position_mm}`);
    const n = [a.normal.x, a.normal.y, a.normal.z];
    for (let j = 0; j < 3; ++j) check(near(n[j], b.normal[j], 1e-12), `${w}.normal`);
    check(near(a.depth * 1000, b.depth_mm, 1e-12), `${w}.depth`);
    check(near(a.force, b.force_n, 1e-12), `${w}.force`);
    check(near(a.u * 1000, b.u_mm, 1e-9) && near(a.v * 1000, b.v_mm, 1e-9), `${w}.u, v`);
    check(near(a.uncertainty * 1000, b.uncertainty_mm, 1e-9), `${w}.uncertainty`);
    check(a.patch_id === b.node, `${w}.patch_id ${a.patch_id} vs ${b.node}`);
    check(a.hardware_uid.toString(16).padStart(16, "0") === b.hardware_uid, `${w}.hardware_uid`);
    check(a.link_name === b.link, `${w}.link_name`);
    check(a.track_id === b.track_id && a.patch_count === b.patch_count, `${w}.track_id, patch_count`);
    check((a.flags === 0) === (b.flags.length === 0), `${w}.flags ${a.flags} vs ${b.flags}`);
    check(usOf(a.first_seen) === b.first_seen_us, `${w}.first_seen`);
    const s = [a.shear.x, a.shear.y, a.shear.z];
    for (let j = 0; j < 3; ++j) check(near(s[j], b.shear_n[j], 1e-12), `${w}.shear`);
    check(near(a.shear_uncertainty, b.shear_uncertainty_n, 1e-12), `${w}.shear_uncertainty`);
    // The wrench from its definition in Contact.msg: -force along the normal plus the shear,
    // its torque about the frame's origin.
    const f = [0, 1, 2].map((j) => -b.force_n * b.normal[j] + b.shear_n[j]);
    const pm = b.position_mm.map((x) => x / 1000);
    const t = [pm[1] * f[2] - pm[2] * f[1], pm[2] * f[0] - pm[0] * f[2], pm[0] * f[1] - pm[1] * f[0]];
    const wf = [a.wrench.force.x, a.wrench.force.y, a.wrench.force.z];
    const wt = [a.wrench.torque.x, a.wrench.torque.y, a.wrench.torque.z];
    for (let j = 0; j < 3; ++j) {
      check(near(wf[j], f[j], 1e-9) && near(wt[j], t[j], 1e-9), `${w}.wrench ${wf} ${wt} vs ${f} ${t}`);
    }
    ++contactsCompared;
  }
}

const recStatus = byTopic("/skin/patch_status")?.messages ?? [];
check(recStatus.length === hostStatus.length,
      `${recStatus.length} status messages recorded, the host printed ${hostStatus.length}`);
for (let i = 0; i < Math.min(recStatus.length, hostStatus.length); ++i) {
  const r = recStatus[i].decoded, h = hostStatus[i], where = `/skin/patch_status[${i}]`;
  check(usOf(r.header.stamp) === h.stamp_us, `${where}: stamp`);
  check(r.patches.length === h.patches.length, `${where}: patches`);
  r.patches.forEach((p, k) => {
    const q = h.patches[k];
    if (!q) return;
    check(p.node === q.node && p.state_name === q.state && Number(p.samples) === q.samples &&
          p.link_name === q.link && p.can_interface === q.interface &&
          near(p.clock_offset * 1e6, q.clock_offset_us, 1e-3 * Math.abs(q.clock_offset_us) * 1e-9 + 1e-3),
          `${where}.patches[${k}]: node ${p.node}/${q.node} state ${p.state_name}/${q.state} samples ${p.samples}/${q.samples}`);
  });
  check(r.events.length === h.events.length, `${where}: events ${r.events.length} vs ${h.events.length}`);
  r.events.forEach((e, k) => {
    const q = h.events[k];
    if (q) {
      check(e.kind_name === q.event && e.detail === q.detail && usOf(e.stamp) === q.time_us,
            `${where}.events[${k}]: ${e.kind_name} vs ${q.event}`);
    }
  });
}
const diag = byTopic("/diagnostics")?.messages ?? [];
check(diag.length === recStatus.length, `${diag.length} diagnostics for ${recStatus.length} status messages`);
for (let i = 0; i < Math.min(diag.length, recStatus.length); ++i) {
  const d = diag[i].decoded, s = recStatus[i].decoded;
  check(d.status.length === s.patches.length, `/diagnostics[${i}]: ${d.status.length} entries`);
  d.status.forEach((e, k) => {
    check([0, 1, 2, 3].includes(e.level), `/diagnostics[${i}].status[${k}].level ${e.level}`);
    check(e.values.some((v) => v.key === "samples"), `/diagnostics[${i}].status[${k}]: no samples value`);
  });
}

const samples = byTopic("/skin/samples")?.messages ?? [];
check(samples.length > 0, "no samples");
for (const [i, s] of samples.entries()) {
  const v = s.decoded;
  check(v.field_ut.length === 48, `/skin/samples[${i}]: ${v.field_ut.length} field values`);
  // The wire carries 0.1 uT steps: every value is one.
  check(v.field_ut.every((f) => near(Math.round(f * 10) / 10, f, 1e-4)), `/skin/samples[${i}]: not in 0.1 uT steps`);
}
const frames = byTopic("/skin/can")?.messages ?? [];
check(frames.length > 0, "no CAN frames");
for (const [i, f] of frames.entries()) {
  const v = f.decoded;
  check(v.data.length <= (v.is_fd ? 64 : 8), `/skin/can[${i}]: ${v.data.length} bytes`);
  check(BigInt(usOf(v.header.stamp)) * 1000n === f.logTime, `/skin/can[${i}]: log time is not its receive time`);
}
const joints = byTopic("/joint_states")?.messages ?? [];
check(joints.length > 0, "no joint states");
for (const [i, j] of joints.entries()) {
  const v = j.decoded;
  check(v.name.length === v.position.length && v.name.length > 0, `/joint_states[${i}]: names and positions`);
}

console.log(`check_mcap: ${indexed} messages read by the indexed and the streaming reader, ` +
  `${[...topics.values()].map((t) => `${t.topic} ${t.messages.length}`).join(", ")}; ` +
  `${contactsCompared} contacts and ${recStatus.length} status messages equal to the host's output`);
if (failures.length > 0) {
  console.log(`FAIL: ${failures.length} check(s):`);
  for (const f of failures.slice(0, 30)) console.log("  " + f);
  process.exit(1);
}
console.log("OK");
