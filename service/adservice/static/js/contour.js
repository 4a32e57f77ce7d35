// The contour view of the params panel: the complete trials' scores over any two params
// (two selects, the two most important by default), interpolated on a grid by inverse
// distance weighting and filled in ten levels of the charts' palette (yellow = best),
// with the trials as dots on top. A log param's axis is on a log scale, an int param of
// few values and a categorical one are bands (one cell each). Hovering names a trial, or
// the values and interpolated score under the pointer; clicking a trial opens it.
//
// Inverse distance weighting (power 2, in each axis's unit range; a categorical axis
// puts other choices at distance 1) rather than a fitted model: it needs nothing but the
// trials, passes through each of them, and stays within the scores seen, so the colours
// never promise a score no trial had. Where there are no trials it only averages the
// nearest ones, which says nothing of what is there: a cell farther than UNEXPLORED (in
// each axis's unit range; another choice of a categorical axis is 1 away) from every
// trial is painted a neutral grey instead, "unexplored" in the legend, never a level of
// the palette (which would paint an empty corner as the best, or the worst, region).

import {
  AXIS,
  PALETTE,
  bindPoints,
  bucket,
  clipText,
  formatNumber,
  labelled,
  message,
  niceTicks,
  prepare,
} from './charts.js';
import { element, esc, finder } from './html.js';
import { paramDomain, scoreDirection } from './importance.js';

const CELLS = 60;
/** The most trials the grid interpolates from (an even sample of more): 60 × 60 cells
 * cost one pass over them each. All are drawn as dots. */
const MAX_SOURCES = 2000;
const REACH = 64; // squared px: how close the pointer must be to name a trial
/** How far (in each axis's unit range) a cell may be from its nearest trial and still
 * be coloured by the interpolation: 15% of the axes' ranges. */
export const UNEXPLORED = 0.15;
const UNEXPLORED_COLOUR = '#d1d5db';

/** Log-scale ticks in [lo, hi] (log10 units): powers of ten, or 1-2-5 steps if too few. */
function logTicks(lo, hi) {
  const within = (ticks) => ticks.filter((t) => t >= lo - 1e-9 && t <= hi + 1e-9);
  const powers = [];
  for (let k = Math.ceil(lo); k <= Math.floor(hi); k++) powers.push(k);
  if (powers.length >= 2) return powers;
  const steps = [];
  for (let k = Math.floor(lo); k <= Math.ceil(hi); k++) {
    for (const m of [1, 2, 5]) steps.push(k + Math.log10(m));
  }
  const found = within(steps);
  if (found.length >= 2) return found;
  return niceTicks(10 ** lo, 10 ** hi, 4).filter((v) => v > 0).map(Math.log10);
}

/**
 * One axis of the contour: where a trial sits on it (`at`, in plot units), the plot
 * units' range, how many cells, each cell's centre, its ticks, and a value's text.
 * Bands (categorical, or an int of at most CELLS values) have one cell per value.
 */
function axisOf(domain) {
  if (domain.kind === 'categorical') {
    const n = domain.labels.length;
    return {
      name: domain.name,
      bands: true,
      categorical: true,
      at: (i) => domain.codes[i],
      lo: -0.5,
      hi: n - 0.5,
      cells: n,
      centre: (k) => k,
      ticks: labelled(domain.labels).map((k) => ({ at: k, text: domain.labels[k] })),
      text: (at) => domain.labels[Math.round(at)] ?? '—',
    };
  }
  const { low, high, log, int } = domain;
  if (int && high - low + 1 <= CELLS) {
    const ticks = niceTicks(low, high, 6).filter(Number.isInteger);
    return {
      name: domain.name,
      bands: true,
      categorical: false,
      at: (i) => domain.values[i],
      lo: low - 0.5,
      hi: high + 0.5,
      cells: high - low + 1,
      centre: (k) => low + k,
      ticks: ticks.map((t) => ({ at: t, text: formatNumber(t) })),
      text: (at) => formatNumber(Math.round(at)),
    };
  }
  const scale = log ? Math.log10 : (v) => v;
  let [lo, hi] = [scale(low), scale(high)];
  if (!(hi > lo)) [lo, hi] = [lo - 0.5, hi + 0.5];
  const ticks = log ? logTicks(lo, hi) : niceTicks(lo, hi, 6);
  const value = (at) => (log ? 10 ** at : at);
  return {
    name: domain.name,
    bands: false,
    categorical: false,
    at: (i) => scale(domain.values[i]),
    lo,
    hi,
    cells: CELLS,
    centre: (k) => lo + ((k + 0.5) / CELLS) * (hi - lo),
    ticks: ticks.map((t) => ({ at: t, text: formatNumber(value(t)) })),
    text: (at) => formatNumber(value(at)),
    log,
  };
}

/** Where plot units `at` sit for distances: in the axis's unit range, or a choice's
 * index for a categorical axis (other choices are 1 away). */
function unit(axis, at) {
  return axis.categorical ? at : (at - axis.lo) / (axis.hi - axis.lo);
}

/** Each grid cell's score, by inverse distance weighting (power 2) of the sources, and
 * (`near`) whether a source lies within UNEXPLORED of it. */
function interpolate(ax, ay, sources) {
  const n = sources.length;
  const sx = Float64Array.from(sources, (s) => unit(ax, s.x));
  const sy = Float64Array.from(sources, (s) => unit(ay, s.y));
  const sv = Float64Array.from(sources, (s) => s.value);
  const along = (axis, cell, source) => (axis.categorical ? (cell === source ? 0 : 1) : cell - source);
  const z = [];
  const near = [];
  const reach = UNEXPLORED * UNEXPLORED;
  for (let gy = 0; gy < ay.cells; gy++) {
    const cy = unit(ay, ay.centre(gy));
    const row = new Float64Array(ax.cells);
    const nearRow = new Array(ax.cells).fill(false);
    for (let gx = 0; gx < ax.cells; gx++) {
      const cx = unit(ax, ax.centre(gx));
      let sum = 0;
      let weights = 0;
      let exact = null;
      let nearest = Infinity;
      for (let k = 0; k < n; k++) {
        const dx = along(ax, cx, sx[k]);
        const dy = along(ay, cy, sy[k]);
        const d2 = dx * dx + dy * dy;
        if (d2 < nearest) nearest = d2;
        if (d2 < 1e-12) {
          exact = sv[k];
          break;
        }
        sum += sv[k] / d2;
        weights += 1 / d2;
      }
      row[gx] = exact ?? sum / weights;
      nearRow[gx] = nearest <= reach;
    }
    z.push(row);
    near.push(nearRow);
  }
  return { z, near };
}

/** A trial's offset within its band, so trials of one choice do not hide each other. */
function jitter(number) {
  return (((number * 0.6180339887) % 1) - 0.5) * 0.5;
}

/**
 * The contour of the score over `nx` (across) and `ny` (up). Leaves on the canvas
 * `data-x`, `data-y`, `data-points`, `data-cells` and `data-low`/`data-high` (the score's
 * range), `canvas.grid` (each cell's centre and score) and `canvas.hit` (the plot area
 * and each dot, for hovering). Returns the score's range and the levels' order, or null
 * when there is nothing to draw.
 */
function drawContour(canvas, series, study, nx, ny) {
  const { ctx, width, height } = prepare(canvas);
  canvas.dataset.x = nx;
  canvas.dataset.y = ny;
  canvas.hit = { points: [], area: null };
  canvas.grid = null;
  const all = series.complete;
  const ax = axisOf(paramDomain(series, nx, study, all));
  const ay = axisOf(paramDomain(series, ny, study, all));
  const present = (axis, i) => {
    const at = axis.at(i);
    return at !== null && at !== undefined && Number.isFinite(at);
  };
  const rows = all.filter((i) => present(ax, i) && present(ay, i));
  canvas.dataset.points = String(rows.length);
  if (rows.length < 3) {
    message(ctx, width, height, `A contour needs 3 complete trials with ${nx} and ${ny}; there are ${rows.length}`);
    canvas.dataset.cells = '';
    return null;
  }
  let low = Infinity;
  let high = -Infinity;
  for (const i of rows) {
    low = Math.min(low, series.value[i]);
    high = Math.max(high, series.value[i]);
  }
  const maximize = scoreDirection(study) === 'maximize';
  const level = (v) => {
    const share = high > low ? (v - low) / (high - low) : 1;
    return bucket(maximize ? share : 1 - share);
  };
  const stride = Math.max(1, rows.length / MAX_SOURCES);
  const sources = [];
  for (let r = 0; r < rows.length; r += stride) {
    const i = rows[Math.floor(r)];
    sources.push({ x: ax.at(i), y: ay.at(i), value: series.value[i] });
  }
  const { z, near } = interpolate(ax, ay, sources);
  let unexplored = 0;

  const pad = { left: 78, right: 14, top: 10, bottom: 42 };
  const right = width - pad.right;
  const bottom = height - pad.bottom;
  const px = (at) => pad.left + ((at - ax.lo) / (ax.hi - ax.lo)) * (right - pad.left);
  const py = (at) => bottom - ((at - ay.lo) / (ay.hi - ay.lo)) * (bottom - pad.top);
  const edgeX = (k) => Math.round(px(ax.lo + (k / ax.cells) * (ax.hi - ax.lo)));
  const edgeY = (k) => Math.round(py(ay.lo + (k / ay.cells) * (ay.hi - ay.lo)));
  for (let gy = 0; gy < ay.cells; gy++) {
    const top = edgeY(gy + 1);
    const size = edgeY(gy) - top;
    for (let gx = 0; gx < ax.cells; gx++) {
      if (!near[gy][gx]) unexplored += 1;
      ctx.fillStyle = near[gy][gx] ? PALETTE[level(z[gy][gx])] : UNEXPLORED_COLOUR;
      ctx.fillRect(edgeX(gx), top, edgeX(gx + 1) - edgeX(gx), size);
    }
  }

  // Axes: ticks and names.
  ctx.strokeStyle = AXIS;
  ctx.fillStyle = AXIS;
  ctx.lineWidth = 1;
  ctx.beginPath();
  ctx.moveTo(pad.left, bottom + 0.5);
  ctx.lineTo(right, bottom + 0.5);
  ctx.moveTo(pad.left - 0.5, pad.top);
  ctx.lineTo(pad.left - 0.5, bottom);
  ctx.stroke();
  ctx.textAlign = 'center';
  ctx.textBaseline = 'top';
  const roomX = (right - pad.left) / Math.max(ax.ticks.length, 1);
  for (const tick of ax.ticks) {
    const x = Math.round(px(tick.at)) + 0.5;
    ctx.beginPath();
    ctx.moveTo(x, bottom);
    ctx.lineTo(x, bottom + 4);
    ctx.stroke();
    ctx.fillText(clipText(ctx, tick.text, Math.max(roomX - 4, 24)), x, bottom + 6);
  }
  ctx.textAlign = 'right';
  ctx.textBaseline = 'middle';
  for (const tick of ay.ticks) {
    const y = Math.round(py(tick.at)) + 0.5;
    ctx.beginPath();
    ctx.moveTo(pad.left - 4, y);
    ctx.lineTo(pad.left, y);
    ctx.stroke();
    ctx.fillText(clipText(ctx, tick.text, pad.left - 30), pad.left - 6, y);
  }
  ctx.fillStyle = '#374151';
  ctx.textAlign = 'center';
  ctx.textBaseline = 'bottom';
  const label = (axis) => `${axis.name}${axis.log ? ' (log)' : ''}`;
  ctx.fillText(clipText(ctx, label(ax), right - pad.left), (pad.left + right) / 2, height - 2);
  ctx.save();
  ctx.translate(12, (pad.top + bottom) / 2);
  ctx.rotate(-Math.PI / 2);
  ctx.textBaseline = 'middle';
  ctx.fillText(clipText(ctx, label(ay), bottom - pad.top), 0, 0);
  ctx.restore();

  // The trials on top.
  const points = rows.map((i) => {
    const n = series.number[i];
    const x = px(ax.at(i) + (ax.bands ? jitter(n) : 0));
    const y = py(ay.at(i) + (ay.bands ? jitter(n * 7 + 3) : 0));
    return { number: n, x, y, value: series.value[i], xText: ax.text(ax.at(i)), yText: ay.text(ay.at(i)) };
  });
  ctx.fillStyle = 'rgba(255, 255, 255, 0.9)';
  ctx.strokeStyle = '#111827';
  for (const p of points) {
    ctx.beginPath();
    ctx.arc(p.x, p.y, 3, 0, 2 * Math.PI);
    ctx.fill();
    ctx.stroke();
  }
  canvas.dataset.cells = `${ax.cells}x${ay.cells}`;
  canvas.dataset.unexplored = String(unexplored);
  canvas.dataset.low = String(low);
  canvas.dataset.high = String(high);
  canvas.grid = {
    x: Array.from({ length: ax.cells }, (_, k) => ax.centre(k)),
    y: Array.from({ length: ay.cells }, (_, k) => ay.centre(k)),
    z: z.map((row) => Array.from(row)),
    explored: near,
  };
  canvas.hit = {
    points,
    area: { left: pad.left, right, top: pad.top, bottom },
    at: (x, y) => {
      const gx = Math.floor(((x - pad.left) / (right - pad.left)) * ax.cells);
      const gy = Math.floor(((bottom - y) / (bottom - pad.top)) * ay.cells);
      const inside = gx >= 0 && gx < ax.cells && gy >= 0 && gy < ay.cells;
      if (!inside) return null;
      return {
        xText: ax.text(ax.centre(gx)),
        yText: ay.text(ay.centre(gy)),
        value: z[gy][gx],
        unexplored: !near[gy][gx],
      };
    },
  };
  return { low, high, maximize, sampled: sources.length < rows.length ? sources.length : 0 };
}

/** The dot within reach of the pointer, else the grid cell under it (or null). */
function pointAt(canvas, x, y) {
  let best = null;
  let bestDistance = REACH;
  for (const point of canvas.hit?.points ?? []) {
    const distance = (point.x - x) ** 2 + (point.y - y) ** 2;
    if (distance < bestDistance) {
      bestDistance = distance;
      best = point;
    }
  }
  return best ?? canvas.hit?.at?.(x, y) ?? null;
}

export class ContourView {
  constructor(page) {
    this.page = page;
    /** The two params picked, [x, y], or null for the two most important. */
    this.chosen = null;
    this.order = [];
    this.root = element(`<div class="contour" data-contour hidden>
      <div class="toolbar">
        <label>x <select data-contour-x></select></label>
        <label>y <select data-contour-y></select></label>
        <span class="meta" data-contour-note></span>
      </div>
      <div class="chart-wrap">
        <canvas class="chart tall" data-contour-canvas></canvas>
        <div class="tooltip" data-tooltip hidden></div>
      </div>
      <div class="contour-legend" data-contour-legend></div>
    </div>`);
    this.$ = finder(this.root);
    this.canvas = this.$('contour-canvas');
    const pick = (which) => (event) => {
      const pair = [...this.pair()];
      const other = 1 - which;
      if (pair[other] === event.target.value) pair[other] = pair[which];
      pair[which] = event.target.value;
      this.chosen = pair;
      this.draw(this.order);
    };
    this.$('contour-x').addEventListener('change', pick(0));
    this.$('contour-y').addEventListener('change', pick(1));
    bindPoints(this.canvas, this.$('tooltip'), {
      nearest: (x, y) => pointAt(this.canvas, x, y),
      describe: (p) => this.describe(p),
      open: (p) => this.page.openTrialByNumber(p.number),
      clickable: (p) => p.number !== undefined,
      flip: true,
    });
  }

  /** A tooltip: a trial's number, params and score, or a cell's values and interpolated score. */
  describe(p) {
    const { x, y } = this.canvas.dataset;
    const trial = p.number !== undefined;
    return (
      (trial ? `<div>trial #${p.number}</div>` : '') +
      `<div>${esc(x)} = ${esc(p.xText)} · ${esc(y)} = ${esc(p.yText)}</div>` +
      `<div>${esc(this.scoreName())} ${trial ? '' : '≈ '}${formatNumber(p.value)}` +
      `${trial ? '' : ' (interpolated)'}</div>` +
      (p.unexplored ? '<div>unexplored: no trial near, so the colour says nothing here</div>' : '')
    );
  }

  scoreName() {
    const names = this.page.study.objective_names ?? [];
    return names.length > 1 ? names[0] : 'score';
  }

  /** The pair drawn: the one picked while both still vary, else the first two of the order. */
  pair() {
    const [x, y] = this.chosen ?? [];
    if (this.chosen && this.order.includes(x) && this.order.includes(y) && x !== y) return this.chosen;
    return this.order.slice(0, 2);
  }

  /** Draw for the params in `order` (those that vary, most important first). */
  draw(order) {
    this.order = order;
    const study = this.page.study;
    const series = this.series ?? this.page.series; // the params panel's: filtered, if so
    const options = order.map((name) => `<option value="${esc(name)}">${esc(name)}</option>`).join('');
    const selects = [this.$('contour-x'), this.$('contour-y')];
    for (const select of selects) {
      if (select.dataset.names !== order.join('\n')) {
        select.dataset.names = order.join('\n');
        select.innerHTML = options;
      }
    }
    const legend = this.$('contour-legend');
    if (order.length < 2) {
      const { ctx, width, height } = prepare(this.canvas);
      message(ctx, width, height, 'A contour needs two params that vary');
      this.canvas.dataset.x = '';
      this.canvas.dataset.y = '';
      legend.replaceChildren();
      return;
    }
    const [nx, ny] = this.pair();
    selects[0].value = nx;
    selects[1].value = ny;
    const drawn = drawContour(this.canvas, series, study, nx, ny);
    this.$('contour-note').textContent = drawn?.sampled
      ? `Interpolated from an even sample of ${drawn.sampled.toLocaleString()} of the complete trials.`
      : '';
    if (!drawn) {
      legend.replaceChildren();
      return;
    }
    const { low, high, maximize } = drawn;
    const step = (high - low) / PALETTE.length;
    const swatches = PALETTE.map((_, k) => {
      const colour = PALETTE[maximize ? k : PALETTE.length - 1 - k];
      const from = formatNumber(low + k * step);
      const to = formatNumber(low + (k + 1) * step);
      return `<i style="background:${colour}" title="${from} to ${to}"></i>`;
    }).join('');
    legend.innerHTML = `<span>${esc(this.scoreName())}</span>
      <span class="num" data-legend-low>${formatNumber(low)}</span>
      <span class="swatches">${swatches}</span>
      <span class="num" data-legend-high>${formatNumber(high)}</span>
      <span class="meta">yellow = best (${maximize ? 'highest' : 'lowest'}); interpolated by inverse
        distance weighting, dots are trials</span>
      <span data-legend-unexplored><i style="background:${UNEXPLORED_COLOUR}"></i> unexplored: no
        trial within ${Math.round(UNEXPLORED * 100)}% of the axes' ranges</span>`;
  }
}
