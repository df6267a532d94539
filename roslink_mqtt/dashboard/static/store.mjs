// The page's one store: the session (who is logged in, the MQTT client), the robots it has seen (model.mjs) and
// the requests in flight. Exposed as window.dashboard for the browser tests and for curious users (publishing
// through it changes nothing: the broker checks every PUBLISH against the login's grants).
import { TopicTree } from "./topics.mjs";
import { SequenceClock } from "./model.mjs";
import { PlotView } from "./geometry.mjs";
import { AlertBook } from "./alerts.mjs";

export const dash = {
  client: null, user: "", clientId: "", prefix: "roslink", config: null, connected: false, everConnected: false,
  tree: new TopicTree("roslink"),  // the broker's prefix, once config.json has said it
  robots: new Map(), selected: null, operatorAnywhere: false, commanding: false,
  presenceSeq: 0, seq: new SequenceClock(), presenceTimer: null, driveTimer: null, driveDir: null, driveRobot: null,
  heldKeys: new Set(), pendingCalls: new Map(), callCounter: 0, waypoint: null,
  goals: new Map(), pendingParams: new Map(), builtFor: null,
  snapshots: new Map(),  // id → a snapshot being received (chunks by index); the finished one stays as .done
  video: null,  // the video stream being watched (views/video.mjs): robot, stream, decoder, recent frames
  cameraUrl: null, undecoded: new Set(),  // the shown raw image's blob URL; states said to be undecodable
  view: new PlotView(),  // the robot view's plot
  alerts: new AlertBook(), rules: null, inspect: null, stopRound: null,
  rateRows: new Map(),  // topic → its row in the shown robot's rates table
  page: "robot",  // the view shown: "fleet" or "robot" (the first robot seen opens its view)
};
if (typeof window !== "undefined") window.dashboard = dash;

export const nextSeq = () => dash.seq.next(Date.now());
export const selectedRobot = () => (dash.selected ? dash.robots.get(dash.selected) || null : null);
