// Snapshots (docs/protocol.md, "Snapshots"): the robot's own ROS messages of its last seconds as MCAP, received in
// chunks, resumed from the first missing one when they stall, checked (SHA-256) and downloaded as a file.
import { read } from "../decode.mjs";
import { dash } from "../store.mjs";
import { addLog, randomHex, show, ui } from "./dom.mjs";
import { publishUser } from "./session.mjs";

const SNAPSHOT_SECONDS = 30;
const SNAPSHOT_STALL_MS = 10000;  // no chunk for this long: ask again from the first missing one
const SNAPSHOT_RESUMES = 20;

export function showSnapshot(robot) { show(ui.snapshotBox, Boolean(robot && robot.access && robot.access.snapshot)); }

function snapshotStatus(state, text) {
  ui.snapshotStatus.dataset.state = state;
  ui.snapshotStatus.textContent = text;
}

function askSnapshot(snap, resumeFrom) {
  const body = { last: SNAPSHOT_SECONDS, client_id: dash.clientId };
  if (resumeFrom) body.resume_from = resumeFrom;
  publishUser(snap.robot, "snapshot", snap.id, body);
  snap.lastChunk = performance.now();
}

export function takeSnapshot() {
  const robot = dash.selected;
  if (!robot || !dash.client) return;
  const id = `d${randomHex(6)}`;
  const snap = { id, robot, chunks: new Map(), header: null, done: false, resumes: 0, lastChunk: 0, timer: null };
  dash.snapshots.set(id, snap);
  ui.snapshot.disabled = true;
  snapshotStatus("asking", `asking ${robot} for its last ${SNAPSHOT_SECONDS} s…`);
  askSnapshot(snap, 0);
  snap.timer = setInterval(() => {
    if (snap.done || performance.now() - snap.lastChunk < SNAPSHOT_STALL_MS) return;
    if (++snap.resumes > SNAPSHOT_RESUMES) { endSnapshot(snap, "failed", "the robot stopped sending; given up"); return; }
    let first = 0;
    while (snap.chunks.has(first)) first += 1;
    askSnapshot(snap, first);
  }, 1000);
}

export function endSnapshot(snap, state, text) {
  snap.done = true;
  clearInterval(snap.timer);
  if (dash.selected === snap.robot) snapshotStatus(state, text);
  ui.snapshot.disabled = false;
  addLog(state === "saved" ? ui.acks : ui.errors, `${snap.robot} snapshot: ${text}`, { robot: snap.robot });
}

export function onSnapshotChunk(robotName, id, payload) {
  const snap = dash.snapshots.get(id);
  if (!snap || snap.done || snap.robot !== robotName) return;
  const bytes = payload instanceof Uint8Array ? payload : new Uint8Array(payload);
  const cut = bytes.indexOf(10);  // the header line ends at the first newline
  const header = cut > 0 ? read("snapshot_chunk", bytes.subarray(0, cut)) : null;
  if (!header) { endSnapshot(snap, "failed", "a malformed chunk"); return; }
  if (snap.header && (header.count !== snap.header.count || header.sha256 !== snap.header.sha256)) {
    endSnapshot(snap, "failed", "chunks of two different files under one id");
    return;
  }
  snap.header = snap.header || header;
  snap.chunks.set(header.index, bytes.slice(cut + 1));
  snap.lastChunk = performance.now();
  if (dash.selected === snap.robot) snapshotStatus("receiving", `${snap.chunks.size} / ${header.count} chunks`);
  if (snap.chunks.size === header.count) finishSnapshot(snap);
}

async function finishSnapshot(snap) {
  const { count, size, sha256, messages } = snap.header;
  const data = new Uint8Array(size);
  let at = 0;
  for (let i = 0; i < count; i += 1) {
    const part = snap.chunks.get(i);
    if (at + part.length > size) { endSnapshot(snap, "failed", "more bytes than the robot announced"); return; }
    data.set(part, at);
    at += part.length;
  }
  const digest = new Uint8Array(await crypto.subtle.digest("SHA-256", data));
  const hex = [...digest].map((b) => b.toString(16).padStart(2, "0")).join("");
  if (at !== size || hex !== sha256) { endSnapshot(snap, "failed", "the file arrived damaged (SHA-256 differs)"); return; }
  snap.file = data;  // kept for the browser tests; the download is the user's copy
  const name = `${snap.robot}-${new Date().toISOString().replace(/[:.]/g, "-")}.mcap`;
  const link = document.createElement("a");
  link.href = URL.createObjectURL(new Blob([data], { type: "application/octet-stream" }));
  link.download = name;
  link.click();
  setTimeout(() => URL.revokeObjectURL(link.href), 60000);
  endSnapshot(snap, "saved", `${name}: ${messages} messages, ${(size / 1000).toFixed(0)} kB, SHA-256 checked`);
}
