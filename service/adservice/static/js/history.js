// The score-by-trial panel: every complete trial's score, the best so far, ticks for
// failed and open trials; hovering names a point, clicking opens its trial. Under
// constraints an infeasible trial is a grey point and never the best so far; a study of
// several objectives charts its first objective, without a best so far (its best
// designs are the Pareto panel's). A log scale toggle spreads scores over decades
// (1e-4 to 60 looks flat on a linear axis); it needs every score above 0.

import { INFEASIBLE, bindPoints, drawXAxis, drawYAxis, extent, formatNumber, message, prepare } from './charts.js';
import { element, finder } from './html.js';

/**
 * Every complete trial's score against its number, the best-so-far curve over them,
 * and ticks for failed (red) and unfinished (grey) trials along the bottom.
 * Leaves on the canvas what hovering needs (`canvas.hit`), and `data-points`,
 * `data-failed`, `data-infeasible`, `data-best-so-far` (the curve's last value) and
 * `data-scale` (`log` or `linear`) for tests. With `log`, the score axis is log10 of
 * the scores where all are above 0 (linear otherwise).
 */
function drawHistory(canvas, series, direction, { bestSoFar = true, log = false } = {}) {
  const { ctx, width, height } = prepare(canvas);
  const pad = { left: 58, right: 14, top: 10, bottom: 28 };
  const numbers = series.complete.map((i) => series.number[i]);
  const values = series.complete.map((i) => series.value[i]);
  const feasible = series.complete.map((i) => series.feasible?.[i] !== false);
  const failed = [];
  const open = [];
  for (let i = 0; i < series.number.length; i++) {
    const state = series.state[i];
    if (state === 'failed') failed.push(series.number[i]);
    else if (state !== 'complete' || series.value[i] === null) open.push(series.number[i]);
  }
  canvas.dataset.points = String(values.length);
  canvas.dataset.failed = String(failed.length);
  canvas.dataset.infeasible = String(feasible.filter((f) => !f).length);
  canvas.dataset.bestSoFar = '';
  canvas.hit = null;
  if (series.number.length === 0) {
    message(ctx, width, height, 'No trials yet');
    return;
  }
  const lastNumber = series.number[series.number.length - 1];
  const xHigh = Math.max(lastNumber, 1);
  const logScale = log && values.length > 0 && values.every((v) => v > 0);
  canvas.dataset.scale = logScale ? 'log' : 'linear';
  const scale = logScale ? Math.log10 : (v) => v;
  const [yLow, yHigh] = extent(values.map(scale));
  const left = pad.left;
  const right = width - pad.right;
  const top = pad.top;
  const bottom = height - pad.bottom;
  const x = (n) => left + ((n - 0) / (xHigh - 0 || 1)) * (right - left);
  const y = (v) => bottom - ((scale(v) - yLow) / (yHigh - yLow)) * (bottom - top);

  drawYAxis(ctx, left, top, bottom, right, yLow, yHigh, y, { log: logScale });
  drawXAxis(ctx, left, right, bottom, 0, xHigh, x, true);

  const size = values.length > 2000 ? 2 : 4;
  for (const [colour, wanted] of [[INFEASIBLE, false], ['rgba(37, 99, 235, 0.5)', true]]) {
    ctx.fillStyle = colour;
    for (let i = 0; i < values.length; i++) {
      if (feasible[i] !== wanted) continue;
      ctx.fillRect(x(numbers[i]) - size / 2, y(values[i]) - size / 2, size, size);
    }
  }
  ctx.fillStyle = 'rgba(220, 38, 38, 0.8)';
  for (const n of failed) ctx.fillRect(x(n) - 0.75, bottom - 7, 1.5, 7);
  ctx.fillStyle = 'rgba(107, 114, 128, 0.6)';
  for (const n of open) ctx.fillRect(x(n) - 0.75, bottom - 4, 1.5, 4);

  const first = feasible.indexOf(true);
  if (bestSoFar && first >= 0) {
    const better = direction === 'maximize' ? (a, b) => a > b : (a, b) => a < b;
    let best = values[first];
    ctx.strokeStyle = '#ea580c';
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.moveTo(x(numbers[first]), y(best));
    for (let i = first + 1; i < values.length; i++) {
      if (feasible[i] && better(values[i], best)) {
        ctx.lineTo(x(numbers[i]), y(best));
        best = values[i];
        ctx.lineTo(x(numbers[i]), y(best));
      }
    }
    ctx.lineTo(x(lastNumber), y(best));
    ctx.stroke();
    ctx.lineWidth = 1;
    canvas.dataset.bestSoFar = String(best);
  }
  canvas.hit = { numbers, values, feasible, x, y };
}

/** The complete trial nearest the pointer (within 12 px), as {number, value}. */
function nearestPoint(canvas, offsetX, offsetY) {
  const hit = canvas.hit;
  if (!hit) return null;
  let best = null;
  let bestDistance = 144;
  for (let i = 0; i < hit.numbers.length; i++) {
    const dx = hit.x(hit.numbers[i]) - offsetX;
    const dy = hit.y(hit.values[i]) - offsetY;
    const distance = dx * dx + dy * dy;
    if (distance < bestDistance) {
      bestDistance = distance;
      best = { number: hit.numbers[i], value: hit.values[i], feasible: hit.feasible[i] };
    }
  }
  return best;
}

export class HistoryPanel {
  constructor(page) {
    this.page = page;
    this.root = element(`<section class="card">
      <h2><span data-history-title>Score by trial</span>
        <span class="legend"><i class="dot"></i>score
        <span data-infeasible-key hidden><i class="dot infeasible"></i>infeasible</span>
        <span data-best-key><i class="line"></i>best so far</span>
        <i class="tick failed"></i>failed <i class="tick open"></i>queued/running</span>
        <label class="meta"><input type="checkbox" data-history-log> log scale</label></h2>
      <div class="chart-wrap">
        <canvas class="chart" data-history></canvas>
        <div class="tooltip" data-tooltip hidden></div>
      </div>
    </section>`);
    const $ = finder(this.root);
    this.$ = $;
    this.canvas = $('history');
    this.log = false;
    $('history-log').addEventListener('change', (event) => {
      this.log = event.target.checked;
      this.draw();
    });
    bindPoints(this.canvas, $('tooltip'), {
      nearest: (x, y) => nearestPoint(this.canvas, x, y),
      describe: (point) =>
        `trial #${point.number}: ${formatNumber(point.value)}` + (point.feasible ? '' : ' (infeasible)'),
      open: (point) => page.openTrialByNumber(point.number),
    });
  }

  draw() {
    const { study, series } = this.page;
    const several = (study.objective_names ?? []).length > 1;
    if (several) this.$('history-title').textContent = `${study.objective_names[0]} by trial`;
    this.$('infeasible-key').hidden = !series.feasible;
    this.$('best-key').hidden = several;
    // A log axis needs every score above 0: the toggle says so where one is not.
    const scores = series.complete.map((i) => series.value[i]);
    const positive = scores.every((v) => v > 0);
    const toggle = this.$('history-log');
    toggle.disabled = !positive;
    toggle.parentElement.title = positive ? 'score axis in powers of ten' : 'a log scale needs every score above 0';
    drawHistory(this.canvas, series, study.direction, { bestSoFar: !several, log: this.log && positive });
  }
}
