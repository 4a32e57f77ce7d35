// The Pareto panel, for a study of several objectives: its complete trials on two of its
// objectives (the two axes picked from selectors when it has three or more), infeasible
// trials greyed, and the Pareto front as the server answers it (GET /studies/{id}/pareto,
// the one source of which trials are on it) highlighted and, for two objectives, joined
// by its staircase. Hovering names a trial and its values, with the picture of a design
// on the front that uploaded one (robot.png); clicking opens the trial's dialog.

import { artifactNames, getJSON } from './api.js';
import { INFEASIBLE, bindPoints, drawXAxis, drawYAxis, extent, formatNumber, message, prepare } from './charts.js';
import { element, esc, finder } from './html.js';

const POINT = 'rgba(37, 99, 235, 0.55)';
const FRONT = '#ea580c';
const MAX_PICTURES = 1000; // the most front trials whose file names one request asks for

/** The study's objective names, or [] for a study of one objective. */
export function objectiveNames(study) {
  const names = study?.objective_names ?? [];
  return names.length > 1 ? names : [];
}

/** An objective's name with the way it is better (↑ maximised, ↓ minimised). */
export function objectiveLabel(study, k) {
  const arrow = study.directions?.[k] === 'minimize' ? '↓' : '↑';
  return `${study.objective_names[k]} ${arrow}`;
}

/** Where the front's staircase turns between two neighbours: the worse of the two in
 * each objective, so the line bounds what the front dominates. */
function corner(a, b, signs) {
  const worse = (u, v, sign) => (sign > 0 ? Math.min(u, v) : Math.max(u, v));
  return [worse(a[0], b[0], signs[0]), worse(a[1], b[1], signs[1])];
}

/**
 * The complete trials with values as points on objectives `kx` and `ky`: infeasible ones
 * grey, the rest blue, the front's trials (`front`, the server's) orange and larger on
 * top. Leaves `canvas.hit.points` (each point's number, id when known, and CSS-pixel
 * position) for hovering, clicking and tests, and `data-points`, `data-front` and
 * `data-infeasible` (how many of each it drew).
 */
function drawPareto(canvas, series, study, front, kx, ky) {
  const { ctx, width, height } = prepare(canvas);
  const pad = { left: 64, right: 14, top: 10, bottom: 40 };
  const onFront = new Set(front.map((trial) => trial.number));
  const points = [];
  for (let i = 0; i < series.number.length; i++) {
    const values = series.values?.[i];
    if (series.state[i] !== 'complete' || !values || onFront.has(series.number[i])) continue;
    const feasible = series.feasible?.[i] !== false;
    points.push({ number: series.number[i], values, feasible, front: false });
  }
  for (const trial of front) {
    if (trial.values) {
      points.push({ number: trial.number, id: trial.id, values: trial.values, feasible: true, front: true });
    }
  }
  canvas.dataset.points = String(points.length);
  canvas.dataset.front = String(points.filter((p) => p.front).length);
  canvas.dataset.infeasible = String(points.filter((p) => !p.feasible).length);
  canvas.dataset.axes = `${kx},${ky}`;
  canvas.hit = { points: [] };
  if (points.length === 0) {
    message(ctx, width, height, 'No complete trials yet');
    return;
  }
  const [xLow, xHigh] = extent(points.map((p) => p.values[kx]));
  const [yLow, yHigh] = extent(points.map((p) => p.values[ky]));
  const right = width - pad.right;
  const bottom = height - pad.bottom;
  const x = (v) => pad.left + ((v - xLow) / (xHigh - xLow)) * (right - pad.left);
  const y = (v) => bottom - ((v - yLow) / (yHigh - yLow)) * (bottom - pad.top);
  drawYAxis(ctx, pad.left, pad.top, bottom, right, yLow, yHigh, y);
  drawXAxis(ctx, pad.left, right, bottom, xLow, xHigh, x, false);
  ctx.fillStyle = '#374151';
  ctx.textAlign = 'center';
  ctx.textBaseline = 'bottom';
  ctx.fillText(objectiveLabel(study, kx), (pad.left + right) / 2, height - 2);
  ctx.save();
  ctx.translate(12, (pad.top + bottom) / 2);
  ctx.rotate(-Math.PI / 2);
  ctx.textBaseline = 'middle';
  ctx.fillText(objectiveLabel(study, ky), 0, 0);
  ctx.restore();

  const size = points.length > 2000 ? 3 : 5;
  for (const [colour, wanted] of [[INFEASIBLE, false], [POINT, true]]) {
    ctx.fillStyle = colour;
    for (const p of points) {
      if (p.front || p.feasible !== wanted) continue;
      ctx.fillRect(x(p.values[kx]) - size / 2, y(p.values[ky]) - size / 2, size, size);
    }
  }
  const best = points.filter((p) => p.front);
  if (objectiveNames(study).length === 2 && best.length > 1) {
    const signs = [kx, ky].map((k) => (study.directions?.[k] === 'minimize' ? -1 : 1));
    const ordered = best.map((p) => [p.values[kx], p.values[ky]]).sort((a, b) => a[0] - b[0]);
    ctx.strokeStyle = FRONT;
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.moveTo(x(ordered[0][0]), y(ordered[0][1]));
    for (let i = 1; i < ordered.length; i++) {
      const [cx, cy] = corner(ordered[i - 1], ordered[i], signs);
      ctx.lineTo(x(cx), y(cy));
      ctx.lineTo(x(ordered[i][0]), y(ordered[i][1]));
    }
    ctx.stroke();
    ctx.lineWidth = 1;
  }
  ctx.fillStyle = FRONT;
  ctx.strokeStyle = '#7c2d12';
  for (const p of best) {
    ctx.beginPath();
    ctx.arc(x(p.values[kx]), y(p.values[ky]), 4.5, 0, 2 * Math.PI);
    ctx.fill();
    ctx.stroke();
  }
  canvas.hit.points = points.map((p) => ({
    number: p.number,
    id: p.id ?? null,
    front: p.front,
    feasible: p.feasible,
    values: p.values,
    x: x(p.values[kx]),
    y: y(p.values[ky]),
  }));
}

/** The point nearest the pointer (within 12 px), front points first when they tie. */
function nearestPoint(canvas, offsetX, offsetY) {
  let best = null;
  let bestDistance = 144;
  for (const point of canvas.hit?.points ?? []) {
    const distance = (point.x - offsetX) ** 2 + (point.y - offsetY) ** 2;
    if (distance < bestDistance || (distance === bestDistance && point.front)) {
      bestDistance = distance;
      best = point;
    }
  }
  return best;
}

export class ParetoPanel {
  constructor(page) {
    this.page = page;
    /** The server's Pareto front: complete feasible trials no other one dominates. */
    this.front = [];
    this.frontIds = new Set();
    this.pictures = {}; // front trial id -> its artifact names
    this.axes = [0, 1];
    this.root = element(`<section class="card" data-pareto-card hidden>
      <h2>Pareto front <span class="meta" data-pareto-count></span>
        <span class="legend"><span><i class="dot front"></i>on the front</span>
        <span data-pareto-line><i class="line front"></i>front</span>
        <span><i class="dot"></i>dominated</span>
        <span data-pareto-infeasible hidden><i class="dot infeasible"></i>infeasible</span></span></h2>
      <div class="toolbar" data-pareto-axes hidden>
        <label>x <select data-pareto-x></select></label>
        <label>y <select data-pareto-y></select></label>
        <span class="meta">The front is over all objectives: a design on it may look dominated on two.</span>
      </div>
      <div class="chart-wrap">
        <canvas class="chart" data-pareto></canvas>
        <div class="tooltip" data-tooltip hidden></div>
      </div>
    </section>`);
    this.$ = finder(this.root);
    this.canvas = this.$('pareto');
    this.bindEvents();
  }

  get shown() {
    return objectiveNames(this.page.study).length > 1;
  }

  bindEvents() {
    const pick = (which) => (event) => {
      const chosen = Number(event.target.value);
      const other = 1 - which;
      if (this.axes[other] === chosen) this.axes[other] = this.axes[which];
      this.axes[which] = chosen;
      this.draw();
    };
    this.$('pareto-x').addEventListener('change', pick(0));
    this.$('pareto-y').addEventListener('change', pick(1));
    bindPoints(this.canvas, this.$('tooltip'), {
      nearest: (x, y) => nearestPoint(this.canvas, x, y),
      describe: (point) => this.describe(point),
      open: (point) => (point.id !== null ? this.page.openTrial(point.id) : this.page.openTrialByNumber(point.number)),
      flip: true,
    });
  }

  /** A point's tooltip: its trial, values, what it is, and a front design's picture. */
  describe(point) {
    const { study } = this.page;
    const values = objectiveNames(study)
      .map((name, k) => `${esc(name)} ${formatNumber(point.values[k])}`)
      .join(' · ');
    const what = point.front ? ' · on the front' : point.feasible ? '' : ' · infeasible';
    const picture =
      point.id !== null && this.pictures[point.id]?.includes('robot.png')
        ? `<img class="thumb" src="/api/v1/trials/${point.id}/artifacts/robot.png" alt="">`
        : '';
    return `<div>trial #${point.number}${what}</div><div>${values}</div>${picture}`;
  }

  async load() {
    if (!this.shown) return;
    this.front = await getJSON(this.page.api('/pareto'));
    this.frontIds = new Set(this.front.map((trial) => trial.id));
    await this.loadPictures();
  }

  /** Uploads do not touch the study: the page asks now and then for new pictures. */
  async loadPictures() {
    if (!this.shown) return;
    const ids = this.front.slice(0, MAX_PICTURES).map((trial) => trial.id);
    this.pictures = await artifactNames(this.page.studyId, ids);
  }

  renderAxes() {
    const names = objectiveNames(this.page.study);
    this.$('pareto-axes').hidden = names.length < 3;
    const options = names.map((name, k) => `<option value="${k}">${esc(name)}</option>`).join('');
    for (const [which, select] of [this.$('pareto-x'), this.$('pareto-y')].entries()) {
      if (select.dataset.names !== names.join('\n')) {
        select.dataset.names = names.join('\n');
        select.innerHTML = options;
      }
      select.value = String(this.axes[which]);
    }
  }

  draw() {
    this.root.hidden = !this.shown;
    if (this.root.hidden) return;
    const { series, study } = this.page;
    const complete = study.n_complete;
    this.$('pareto-count').textContent =
      `${this.front.length} of ${complete} complete trial${complete === 1 ? '' : 's'}`;
    this.$('pareto-line').hidden = objectiveNames(study).length !== 2;
    this.$('pareto-infeasible').hidden = !series.feasible;
    this.renderAxes();
    drawPareto(this.canvas, series, study, this.front, this.axes[0], this.axes[1]);
  }
}
