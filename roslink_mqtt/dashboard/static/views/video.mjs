// Video (docs/video.md): the selected robot's cameras, watched on demand and decoded by the browser (WebCodecs) onto
// a canvas. Watching is a lease renewed every few seconds (watch/<stream>); the robot encodes only while someone
// watches, and stops when the last watcher leaves. A frame after a gap waits for a keyframe, which is asked for.
import { read } from "../decode.mjs";
import { dash } from "../store.mjs";
import { addLog, el, setText, show, ui } from "./dom.mjs";
import { publishUser } from "./session.mjs";

const RENEW_MS = 3000;  // WATCH_RENEW (roslink_mqtt/protocol/video.py): the robot's lease is 10 s
const KEY_ASK_MS = 1000;  // at most one keyframe request a second (the robot sends at most one a second anyway)

/** The watch panel of `robot`: its video streams (the description's `video` entries), or hidden. */
export function showVideo(robot) {
  const streams = robot && robot.description && Array.isArray(robot.description.video) ? robot.description.video : [];
  show(ui.videoBox, streams.length > 0 && typeof VideoDecoder !== "undefined");
  const names = streams.map((s) => s.name);
  if ([...ui.videoStream.options].map((o) => o.value).join("\n") !== names.join("\n")) {
    ui.videoStream.replaceChildren(...names.map((n) => el("option", { value: n }, n)));
  }
  if (dash.video && (!robot || dash.video.robot !== robot.name)) stopWatching();
}

export function toggleWatch() {
  if (dash.video) { stopWatching(); return; }
  const robot = dash.selected;
  const stream = ui.videoStream.value;
  if (!robot || !stream || !dash.client) return;
  const v = { robot, stream, decoder: null, profile: null, nextSeq: null, keyAsked: 0, shown: 0, frames: [],
              timer: null, canvas: ui.videoCanvas.getContext("2d") };
  dash.video = v;
  ui.videoWatch.textContent = "Stop watching";
  ui.videoCanvas.dataset.frames = "0";
  askWatch(v, true);
  v.timer = setInterval(() => { askWatch(v, false); showStats(v); }, RENEW_MS);
  setText(ui.videoStats, `asking ${robot} for ${stream}…`);
}

function askWatch(v, key) {
  if (!dash.client || !dash.connected || dash.video !== v) return;  // logged out, or watching something else now
  publishUser(v.robot, "watch", v.stream, key ? { client_id: dash.clientId, key: true } : { client_id: dash.clientId },
              0);
  if (key) v.keyAsked = performance.now();
}

export function stopWatching() {
  const v = dash.video;
  if (!v) return;
  dash.video = null;
  clearInterval(v.timer);
  if (dash.client && dash.connected) publishUser(v.robot, "watch", v.stream, { client_id: dash.clientId, leave: true }, 0);
  if (v.decoder && v.decoder.state !== "closed") v.decoder.close();
  ui.videoWatch.textContent = "Watch";
  setText(ui.videoStats, "");
}

/** Whether `state/<name>` of `robotName` is the stream being watched (incoming.mjs hands its frames here). */
export function isWatched(robotName, name) {
  return Boolean(dash.video && dash.video.robot === robotName && dash.video.stream === name);
}

/** One frame of the watched stream: a JSON header line, a newline, the bitstream (docs/protocol.md, "video frame"). */
export function onVideoFrame(payload) {
  const v = dash.video;
  const bytes = payload instanceof Uint8Array ? payload : new Uint8Array(payload);
  const cut = bytes.indexOf(10);
  const header = cut > 0 ? read("video_frame", bytes.subarray(0, cut)) : null;
  if (!v || !header) return;
  const now = performance.now();
  v.frames.push({ at: now, bytes: bytes.length, age: Date.now() / 1000 - header.stamp });
  while (v.frames.length && now - v.frames[0].at > 2000) v.frames.shift();
  if (!v.decoder || v.decoder.state === "closed" || v.profile !== header.profile) {
    if (!header.key) { askKey(v, now); return; }
    configure(v, header);
  }
  if (!header.key && v.nextSeq !== header.seq) { v.nextSeq = null; askKey(v, now); return; }
  v.nextSeq = header.seq + 1;
  try {
    v.decoder.decode(new EncodedVideoChunk({ type: header.key ? "key" : "delta",
                                             timestamp: Math.round(header.stamp * 1e6),
                                             data: bytes.subarray(cut + 1) }));
    v.lastHeader = header;
  } catch (e) {
    v.nextSeq = null;
    askKey(v, now);
  }
}

function configure(v, header) {
  if (v.decoder && v.decoder.state !== "closed") v.decoder.close();
  v.profile = header.profile;
  v.decoder = new VideoDecoder({
    output: (picture) => draw(v, picture),
    error: (e) => {
      addLog(ui.errors, `${v.robot} ${v.stream}: the browser could not decode the video (${e.message})`,
             { robot: v.robot });
      v.profile = null;  // a new decoder at the next keyframe
    },
  });
  v.decoder.configure({ codec: header.profile, optimizeForLatency: true });
}

function askKey(v, now) {
  if (now - v.keyAsked >= KEY_ASK_MS) askWatch(v, true);
}

function draw(v, picture) {
  if (dash.video !== v) { picture.close(); return; }
  const canvas = ui.videoCanvas;
  if (canvas.width !== picture.displayWidth || canvas.height !== picture.displayHeight) {
    canvas.width = picture.displayWidth;
    canvas.height = picture.displayHeight;
  }
  v.canvas.drawImage(picture, 0, 0);
  picture.close();
  v.shown += 1;
  canvas.dataset.frames = String(v.shown);
  if (v.lastHeader) canvas.dataset.age = String(Math.round((Date.now() / 1000 - v.lastHeader.stamp) * 1000));
  if (v.shown % 10 === 1) showStats(v);
}

function showStats(v) {
  if (dash.video !== v) return;
  const f = v.frames;
  if (!f.length) { setText(ui.videoStats, `waiting for ${v.stream}…`); return; }
  const span = Math.max(0.5, (f[f.length - 1].at - f[0].at) / 1000);
  const kbit = f.reduce((s, x) => s + x.bytes, 0) * 8 / 1000 / span;
  const ages = f.map((x) => x.age).sort((a, b) => a - b);
  const h = v.lastHeader;
  setText(ui.videoStats, `${(f.length / span).toFixed(0)} fps · ${kbit.toFixed(0)} kbit/s · age ` +
          `${(ages[Math.floor(ages.length / 2)] * 1000).toFixed(0)} ms` + (h ? ` · ${h.width}×${h.height} ${h.codec}` : ""));
}
