// Small drawing steps the plot, the fleet map and the GPS track share (a 2-D canvas context `g`).

/** A line through `points` ([x, y] in world units), placed by `toPx`. */
export function polyline(g, points, toPx, colour, width) {
  if (points.length < 2) return;
  g.strokeStyle = colour;
  g.lineWidth = width;
  g.beginPath();
  points.forEach(([x, y], i) => { const [px, py] = toPx(x, y); if (i) g.lineTo(px, py); else g.moveTo(px, py); });
  g.stroke();
}

/** The two axes through the world origin at pixel (ox, oy), across the whole canvas. */
export function axes(g, canvas, [ox, oy], colour) {
  g.strokeStyle = colour;
  g.lineWidth = 1;
  g.beginPath();
  g.moveTo(ox, 0); g.lineTo(ox, canvas.height); g.moveTo(0, oy); g.lineTo(canvas.width, oy);
  g.stroke();
}

/** Small grey text (scale, axis names). */
export function caption(g, text, x, y) {
  g.fillStyle = "#7b8590";
  g.font = "11px sans-serif";
  g.fillText(text, x, y);
}
