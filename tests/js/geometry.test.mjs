// The plot's and the fleet map's geometry (roslink_mqtt/dashboard/static/geometry.mjs).
import test from "node:test";
import assert from "node:assert";

import { MAX_HALF, MIN_HALF, PlotView, TILE, fitPoints, gridStep, gridValues, mercator, tileUrl, tilesFor,
         zoomToFit } from "../../roslink_mqtt/dashboard/static/geometry.mjs";

const near = (a, b, eps = 1e-9) => assert.ok(Math.abs(a - b) < eps, `${a} != ${b}`);

test("world ↔ pixels: x right, y up, the centre in the middle; the round trip is exact", () => {
  const v = new PlotView();
  assert.deepStrictEqual(v.toPx(600, 600, 0, 0), [300, 300]);
  assert.deepStrictEqual(v.toPx(600, 600, 6, 6), [600, 0]);
  const [x, y] = v.fromPx(600, 600, ...v.toPx(600, 600, 1.25, -2.5));
  near(x, 1.25); near(y, -2.5);
});

test("zoom keeps the point under the cursor, within bounds, and marks the view as the user's", () => {
  const v = new PlotView();
  v.zoom(0.5, [2, 2]);
  assert.strictEqual(v.half, 3);
  near(v.cx, 1); near(v.cy, 1);
  assert.ok(v.manual);
  v.zoom(1e-9);
  assert.strictEqual(v.half, MIN_HALF);
  v.zoom(1e12);
  assert.strictEqual(v.half, MAX_HALF);
});

test("tracking: grows to keep the robot in view until the user moves it; follow centres on it", () => {
  const v = new PlotView();
  v.track({ x: 10, y: 0 });
  assert.strictEqual(v.half, 12);
  v.track({ x: 1, y: 0 });
  assert.strictEqual(v.half, 12);  // never shrinks by itself
  v.manual = true;
  v.track({ x: 100, y: 0 });
  assert.strictEqual(v.half, 12);
  v.follow = true;
  v.track({ x: 100, y: -3 });
  assert.deepStrictEqual([v.cx, v.cy], [100, -3]);
  v.reset();
  assert.deepStrictEqual([v.half, v.cx, v.cy, v.manual, v.follow], [6, 0, 0, false, false]);
});

test("grid: 1-2-5 steps, 4 to 13 lines across, values without float fuzz", () => {
  assert.deepStrictEqual([0.5, 6, 12, 30, 100, 1000].map(gridStep), [0.1, 1, 2, 5, 20, 200]);
  for (let half = MIN_HALF; half <= MAX_HALF; half *= 1.7) {
    const lines = gridValues(-half, half, gridStep(half)).length;
    assert.ok(lines >= 4 && lines <= 13, `${half}: ${lines}`);
  }
  assert.deepStrictEqual(gridValues(0.25, 0.95, 0.1), [0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9]);
});

test("fit: every point inside the square view, at least the minimum size", () => {
  assert.deepStrictEqual(fitPoints([]), { cx: 0, cy: 0, half: 3 });
  const f = fitPoints([[-10, 0], [10, 4]]);
  assert.deepStrictEqual([f.cx, f.cy], [0, 2]);
  assert.ok(f.half >= 10);
});

test("Web Mercator: known points, and the zoom that fits two robots 1 km apart", () => {
  assert.deepStrictEqual(mercator(0, 0, 0), [128, 128]);
  const [x, y] = mercator(85.05112878, 180, 1);
  near(x, 512); near(y, 0, 1e-6);
  const pts = [[48.137, 11.575], [48.146, 11.575]];
  const z = zoomToFit(pts, 560, 320);
  const dy = mercator(...pts[1], z)[1] - mercator(...pts[0], z)[1];
  assert.ok(Math.abs(dy) < 320 * 0.8 && Math.abs(dy) > 320 * 0.2, `${z}: ${dy}`);
  assert.strictEqual(zoomToFit(pts.slice(0, 1), 560, 320), 18);
});

test("tiles: those covering the canvas, wrapped in x, none outside the world in y", () => {
  const t = tilesFor(-10, -10, 300, 200, 1);
  assert.ok(t.every((k) => k.y >= 0 && k.y < 2 && k.x >= 0 && k.x < 2));
  assert.deepStrictEqual(t.filter((k) => k.y === 0).map((k) => [k.x, k.px]), [[1, -TILE + 10], [0, 10], [1, TILE + 10]]);
  assert.strictEqual(tileUrl("https://t.example/{z}/{x}/{y}.png", { z: 3, x: 4, y: 5 }), "https://t.example/3/4/5.png");
});
