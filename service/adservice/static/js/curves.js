// The learning-curves panel: every reported curve of the study's latest trials on one
// chart (the values workers report while training, POST /trials/{id}/report), pruned
// and paused trials in their own colours; hidden while no trial has reported.

import { getJSON } from './api.js';
import { drawXAxis, drawYAxis, extent, message, prepare } from './charts.js';
import { element, finder } from './html.js';

const COLOURS = {
  complete: 'rgba(37, 99, 235, 0.55)',
  pruned: 'rgba(217, 119, 6, 0.6)',
  paused: 'rgba(124, 58, 237, 0.7)',
  running: 'rgba(107, 114, 128, 0.8)',
};

/**
 * Each curve as a line of value against learner step. Leaves `data-curves` (lines drawn)
 * and `data-pruned` (of them, pruned trials') for tests.
 */
function drawCurves(canvas, curves) {
  const { ctx, width, height } = prepare(canvas);
  const drawn = curves.filter((c) => c.steps.length > 0);
  canvas.dataset.curves = String(drawn.length);
  canvas.dataset.pruned = String(drawn.filter((c) => c.state === 'pruned').length);
  if (drawn.length === 0) {
    message(ctx, width, height, 'No reports yet');
    return;
  }
  const pad = { left: 58, right: 14, top: 10, bottom: 28 };
  const [xLow, xHigh] = extent(drawn.flatMap((c) => c.steps));
  const [yLow, yHigh] = extent(drawn.flatMap((c) => c.values));
  const bottom = height - pad.bottom;
  const right = width - pad.right;
  const x = (v) => pad.left + ((v - xLow) / (xHigh - xLow)) * (right - pad.left);
  const y = (v) => bottom - ((v - yLow) / (yHigh - yLow)) * (bottom - pad.top);
  drawYAxis(ctx, pad.left, pad.top, bottom, right, yLow, yHigh, y);
  drawXAxis(ctx, pad.left, right, bottom, xLow, xHigh, x, true);
  ctx.lineWidth = 1.5;
  // Finished curves first, so running ones are drawn on top of them.
  const order = (c) => (c.state === 'running' ? 1 : 0);
  for (const curve of [...drawn].sort((a, b) => order(a) - order(b))) {
    ctx.strokeStyle = COLOURS[curve.state] ?? COLOURS.running;
    ctx.beginPath();
    curve.steps.forEach((step, i) => {
      const px = x(step);
      const py = y(curve.values[i]);
      if (i === 0) ctx.moveTo(px, py);
      else ctx.lineTo(px, py);
    });
    if (curve.steps.length === 1) ctx.arc(x(curve.steps[0]), y(curve.values[0]), 1.5, 0, 2 * Math.PI);
    ctx.stroke();
  }
  ctx.lineWidth = 1;
}

export class CurvesPanel {
  constructor(page) {
    this.page = page;
    this.curves = [];
    this.root = element(`<section class="card" hidden>
      <h2>Learning curves
        <span class="legend"><i class="line curve"></i>complete <i class="line pruned"></i>pruned
        <i class="line paused"></i>paused <i class="line open"></i>running</span>
        <span class="meta" data-more hidden>(the latest 200 trials that reported)</span></h2>
      <div class="chart-wrap"><canvas class="chart" data-curves></canvas></div>
    </section>`);
    const $ = finder(this.root);
    this.canvas = $('curves');
    this.more = $('more');
  }

  /** Reports arrive while trials run, without changing the study's counts: a page with
   * running trials reloads the curves on every poll. */
  wanted(study) {
    return study.n_running > 0 || this.curves.length === 0;
  }

  async load() {
    const answer = await getJSON(`/api/v1/dashboard/studies/${this.page.studyId}/curves`);
    this.curves = answer.curves;
    this.more.hidden = !answer.more;
  }

  draw() {
    this.root.hidden = this.curves.length === 0;
    if (!this.root.hidden) drawCurves(this.canvas, this.curves);
  }
}
