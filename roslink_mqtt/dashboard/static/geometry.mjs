// Where things go on a canvas: the robot view's plot (world metres, x right, y up, zoom, pan, follow) and the
// fleet map (local frames, or latitude/longitude in Web Mercator with optional map tiles). Pure: no page;
// tests/js/geometry.test.mjs checks it under node.

export const MIN_HALF = 0.5;
export const MAX_HALF = 1000;
export const HOME = { half: 6, cx: 0, cy: 0 };

/** A square view of the plane: `half` metres from the centre (cx, cy) to each edge. `manual` once the user zoomed
 * or panned (the view then stops growing by itself); `follow`: centred on the robot at every frame. */
export class PlotView {
  constructor() { this.reset(); }

  reset() { Object.assign(this, HOME, { manual: false, follow: false }); }

  scale(width) { return width / (2 * this.half); }
  toPx(width, height, x, y) {
    const s = this.scale(width);
    return [width / 2 + (x - this.cx) * s, height / 2 - (y - this.cy) * s];
  }
  fromPx(width, height, px, py) {
    const s = this.scale(width);
    return [this.cx + (px - width / 2) / s, this.cy - (py - height / 2) / s];
  }

  /** Zoom by `factor` (> 1 out) keeping the world point `anchor` ([x, y], default the centre) where it is. */
  zoom(factor, anchor) {
    const [ax, ay] = anchor || [this.cx, this.cy];
    const half = Math.min(MAX_HALF, Math.max(MIN_HALF, this.half * factor));
    this.cx = ax - (ax - this.cx) * half / this.half;
    this.cy = ay - (ay - this.cy) * half / this.half;
    this.half = half;
    this.manual = true;
  }

  /** Keep `pose` in view: centred on it when following, else growing (never shrinking) until not moved by hand. */
  track(pose) {
    if (!pose) return;
    if (this.follow) { this.cx = pose.x; this.cy = pose.y; return; }
    if (this.manual) return;
    const need = Math.max(Math.abs(pose.x - this.cx), Math.abs(pose.y - this.cy)) + 1.5;
    if (need > this.half) this.half = Math.min(MAX_HALF, Math.ceil(need));
  }
}

/** Grid spacing in metres for a view `half` metres wide each way: the smallest 1-2-5 step of at least half / 6,
 * so 4 to 13 lines across. */
export function gridStep(half) {
  const raw = half / 6;
  const p = 10 ** Math.floor(Math.log10(raw));
  const m = raw / p;
  return +((m <= 1 ? 1 : m <= 2 ? 2 : m <= 5 ? 5 : 10) * p).toPrecision(12);
}

/** The grid lines' values from lo to hi (inclusive) at `step`, without floating-point fuzz (0.30000000000000004). */
export function gridValues(lo, hi, step) {
  const out = [];
  for (let i = Math.ceil(lo / step); i * step <= hi + 1e-9; i += 1) out.push(+(i * step).toPrecision(12));
  return out;
}

/** The smallest square view (centre, half) holding every point with a margin, at least `minHalf` wide. */
export function fitPoints(points, minHalf = 3) {
  if (!points.length) return { cx: 0, cy: 0, half: minHalf };
  let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
  for (const [x, y] of points) {
    x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y);
  }
  return { cx: (x0 + x1) / 2, cy: (y0 + y1) / 2, half: Math.max(minHalf, (x1 - x0) / 2 * 1.2 + 1, (y1 - y0) / 2 * 1.2 + 1) };
}

// ---- latitude/longitude: Web Mercator (the projection of every common tile server), in world pixels at zoom z
export const TILE = 256;
export const MAX_ZOOM = 19;

export function mercator(lat, lon, z) {
  const n = TILE * 2 ** z;
  const la = Math.max(-85.05112878, Math.min(85.05112878, lat)) * Math.PI / 180;
  return [(lon + 180) / 360 * n, (1 - Math.log(Math.tan(la) + 1 / Math.cos(la)) / Math.PI) / 2 * n];
}

/** The zoom level (integer, ≤ MAX_ZOOM) at which every [lat, lon] fits a width × height canvas with a margin. */
export function zoomToFit(points, width, height, maxZoom = 18) {
  if (points.length < 2) return maxZoom;
  for (let z = maxZoom; z > 0; z -= 1) {
    const px = points.map(([la, lo]) => mercator(la, lo, z));
    const w = Math.max(...px.map((p) => p[0])) - Math.min(...px.map((p) => p[0]));
    const h = Math.max(...px.map((p) => p[1])) - Math.min(...px.map((p) => p[1]));
    if (w < width * 0.8 && h < height * 0.8) return z;
  }
  return 0;
}

/** The tiles covering a canvas whose top-left corner is world pixel (left, top) at zoom z: [{z, x, y, px, py}]. */
export function tilesFor(left, top, width, height, z) {
  const n = 2 ** z, out = [];
  for (let ty = Math.floor(top / TILE); ty * TILE < top + height; ty += 1) {
    if (ty < 0 || ty >= n) continue;
    for (let tx = Math.floor(left / TILE); tx * TILE < left + width; tx += 1) {
      out.push({ z, x: ((tx % n) + n) % n, y: ty, px: tx * TILE - left, py: ty * TILE - top });
    }
  }
  return out;
}

/** A tile's URL from a template with {z}, {x} and {y} (the page's settings, from `dashboard --tiles`). */
export function tileUrl(template, t) {
  return template.replace("{z}", String(t.z)).replace("{x}", String(t.x)).replace("{y}", String(t.y));
}
