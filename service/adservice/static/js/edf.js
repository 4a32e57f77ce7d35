// The empirical distribution function (optuna-dashboard's EDF plot): for each of one or
// more groups of scores, the fraction of them at or below each score x, as a step line.
// The study page draws its complete trials' scores; the comparison page one line per study.

import { AXIS, drawXAxis, drawYAxis, extent, message, prepare } from './charts.js';

/** One colour per compared study (the study page's line is the first). */
export const LINE_COLOURS = ['#2563eb', '#ea580c', '#16a34a', '#9333ea', '#dc2626', '#0891b2', '#ca8a04', '#4b5563'];

/**
 * Draw the EDF of each group ({label, values}) on `canvas`. Leaves `data-edf-curves` (JSON:
 * each group's label, count and its curve's steps [[x, fraction]]) for the browser tests.
 */
export function drawEdf(canvas, groups) {
  const { ctx, width, height } = prepare(canvas);
  const curves = groups.map((group) => {
    const sorted = group.values.filter((v) => typeof v === 'number' && Number.isFinite(v)).sort((a, b) => a - b);
    const steps = sorted.map((v, k) => [v, (k + 1) / sorted.length]);
    return { label: group.label, n: sorted.length, steps };
  });
  canvas.dataset.edfCurves = JSON.stringify(curves);
  const all = curves.flatMap((c) => c.steps.map(([v]) => v));
  if (all.length === 0) {
    message(ctx, width, height, 'No complete trials yet');
    return;
  }
  const pad = { left: 44, right: 12, top: 10, bottom: 24 };
  const [low, high] = extent(all);
  const right = width - pad.right;
  const bottom = height - pad.bottom;
  const x = (v) => pad.left + ((v - low) / (high - low)) * (right - pad.left);
  const y = (f) => bottom - f * (bottom - pad.top);
  drawYAxis(ctx, pad.left, pad.top, bottom, right, 0, 1, y);
  drawXAxis(ctx, pad.left, right, bottom, low, high, x, false);
  curves.forEach((curve, k) => {
    if (curve.n === 0) return;
    ctx.strokeStyle = LINE_COLOURS[k % LINE_COLOURS.length];
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.moveTo(pad.left, y(0));
    let fraction = 0;
    for (const [v, f] of curve.steps) {
      ctx.lineTo(x(v), y(fraction));
      ctx.lineTo(x(v), y(f));
      fraction = f;
    }
    ctx.lineTo(right, y(fraction));
    ctx.stroke();
  });
  ctx.lineWidth = 1;
  ctx.fillStyle = AXIS;
}

/** The study page's EDF card: its complete trials' scores (a study of several
 * objectives: its first objective, as the other score charts). */
export class EdfPanel {
  constructor(page) {
    this.page = page;
    this.root = document.createElement('section');
    this.root.className = 'card';
    this.root.innerHTML = `<h2>Empirical distribution
        <span class="legend">fraction of complete trials with a score ≤ x</span></h2>
      <canvas class="chart" data-edf></canvas>`;
    this.canvas = this.root.querySelector('[data-edf]');
  }

  draw() {
    const { series, study } = this.page;
    drawEdf(this.canvas, [{ label: study.name, values: series.complete.map((i) => series.value[i]) }]);
  }
}
