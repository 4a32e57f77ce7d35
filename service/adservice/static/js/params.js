// The params-and-score panel: parallel coordinates, slice plots, rank correlations,
// parameter importance (importance.js) and a contour of two params (contour.js) against
// the score, over complete trials, one tab each.

import {
  AXIS,
  FONT,
  PALETTE,
  bucket,
  clipText,
  drawXAxis,
  drawYAxis,
  extent,
  formatNumber,
  goodness,
  labelled,
  message,
  prepare,
} from './charts.js';
import { ContourView } from './contour.js';
import { element, esc, finder } from './html.js';
import { pedAnova, renderImportance, varyingParams } from './importance.js';
import { SCORE } from './filters.js';
import { isChoices } from './series.js';

const PARALLEL_AXES = 8;
const SLICE_PLOTS = 12;

const MAX_LINES = 2500;

/**
 * A param's column as numbers to plot, and for a categorical param the labels of its
 * ticks: its choices in the space's order (each plotted at its index), or, without a
 * space that names them, the text values in order of appearance.
 */
function plotted(series, name, study) {
  const column = series.params[name];
  const spec = study.space?.params?.find?.((param) => param.name === name);
  if (spec?.type !== 'categorical' && !isChoices(column)) return { column, labels: null };
  const labels = spec?.choices ?? [...new Set(column.filter((v) => v !== null && v !== undefined))];
  const index = new Map(labels.map((choice, i) => [choice, i]));
  return {
    column: column.map((value) => index.get(value) ?? null),
    labels: labels.map(String),
  };
}

/** A filtered-out trial's line: light grey, under the others. */
const FILTERED_OUT = 'rgba(156, 163, 175, 0.35)';
const BRUSH = 'rgba(37, 99, 235, 0.18)';

/**
 * Polylines across the axes `names` and the score, coloured by rank of score (yellow =
 * best), drawn worst first so the best lie on top. Past MAX_LINES complete trials it
 * draws the best half of that many and an even sample of the rest (rasterising
 * thousands of translucent lines is what costs), and says so in its return value.
 * With `filters` active, the trials that fail them are grey lines under the rest, and
 * each filtered axis shows its brushed range. Leaves `canvas.axes` (each axis's name,
 * x, range and choices) for brushing, and `data-axes`, `data-passing` for the tests.
 */
function drawParallel(canvas, series, names, direction, study, filters, everything) {
  const { ctx, width, height } = prepare(canvas);
  const { complete } = series;
  canvas.dataset.lines = String(complete.length);
  canvas.dataset.axes = JSON.stringify(names);
  canvas.axes = null;
  if (complete.length === 0 || names.length === 0) {
    message(ctx, width, height, complete.length ? 'No numeric params vary yet' : 'No complete trials yet');
    canvas.dataset.drawn = '0';
    return { drawn: 0, total: complete.length, best: 0 };
  }
  const allGood = goodness(complete.map((i) => series.value[i]), direction);
  let rows = complete;
  let kept = null;
  let best = complete.length;
  if (complete.length > MAX_LINES) {
    best = MAX_LINES / 2;
    const threshold = 1 - best / complete.length;
    const others = complete.length - best;
    const stride = others / (MAX_LINES - best);
    kept = [];
    let seen = 0;
    let next = 0;
    complete.forEach((_, r) => {
      if (allGood[r] >= threshold) kept.push(r);
      else if (seen++ >= next) {
        kept.push(r);
        next += stride;
      }
    });
    rows = kept.map((r) => complete[r]);
  }
  canvas.dataset.drawn = String(rows.length);
  const pad = { left: 40, right: 48, top: 34, bottom: 22 };
  const axes = [...names.map((name) => plotted(series, name, study)), { column: series.value }];
  const columns = axes.map((axis) => axis.column);
  // A study of several objectives is charted on its first objective (series.js).
  const labels = [...names, study.objective_names?.length > 1 ? study.objective_names[0] : 'score'];
  canvas.dataset.ticks = JSON.stringify(
    Object.fromEntries(names.map((name, k) => [name, axes[k].labels]).filter(([, ticks]) => ticks)),
  );
  const ranges = axes.map(({ column, labels: ticks }) =>
    ticks ? [-0.5, ticks.length - 0.5] : extent(rows.map((i) => column[i])),
  );
  const span = (width - pad.left - pad.right) / Math.max(columns.length - 1, 1);
  const axisX = columns.map((_, k) => pad.left + k * span);
  const top = pad.top;
  const bottom = height - pad.bottom;
  const y = (k, v) => bottom - ((v - ranges[k][0]) / (ranges[k][1] - ranges[k][0])) * (bottom - top);

  const good = kept ? kept.map((r) => allGood[r]) : allGood;
  const paths = PALETTE.map(() => new Path2D());
  const greyed = new Path2D();
  let passing = 0;
  rows.forEach((i, r) => {
    const passes = !filters.active || filters.passes(everything, i);
    if (passes) passing += 1;
    const path = passes ? paths[bucket(good[r])] : greyed;
    let pen = false;
    columns.forEach((column, k) => {
      const value = column[i];
      if (value === null || value === undefined) {
        pen = false;
        return;
      }
      if (pen) path.lineTo(axisX[k], y(k, value));
      else path.moveTo(axisX[k], y(k, value));
      pen = true;
    });
  });
  canvas.dataset.passing = String(passing);
  ctx.lineWidth = 1;
  ctx.strokeStyle = FILTERED_OUT;
  ctx.stroke(greyed);
  ctx.globalAlpha = rows.length <= 50 ? 0.85 : Math.max(0.06, 6 / Math.sqrt(rows.length));
  paths.forEach((path, b) => {
    ctx.strokeStyle = PALETTE[b];
    ctx.stroke(path);
  });
  ctx.globalAlpha = 1;

  // The brushed ranges, and where each axis is (for brushing).
  const keys = [...names, SCORE];
  canvas.axes = {
    top,
    bottom,
    list: keys.map((name, k) => ({ name, x: axisX[k], range: ranges[k], labels: axes[k].labels })),
  };
  keys.forEach((name, k) => {
    const range = filters.ranges.get(name);
    if (!range) return;
    let from;
    let to;
    if (range.choices) {
      const at = axes[k].labels.map((label, index) => (range.choices.has(label) ? index : null)).filter((v) => v !== null);
      if (at.length === 0) return;
      [from, to] = [Math.min(...at) - 0.4, Math.max(...at) + 0.4];
    } else {
      [from, to] = [Math.max(range.low, ranges[k][0]), Math.min(range.high, ranges[k][1])];
    }
    ctx.fillStyle = BRUSH;
    ctx.strokeStyle = '#2563eb';
    ctx.fillRect(axisX[k] - 6, y(k, to), 12, y(k, from) - y(k, to));
    ctx.strokeRect(axisX[k] - 6 + 0.5, y(k, to) + 0.5, 11, y(k, from) - y(k, to));
  });

  ctx.textBaseline = 'middle';
  columns.forEach((_, k) => {
    const px = Math.round(axisX[k]) + 0.5;
    ctx.strokeStyle = '#111827';
    ctx.beginPath();
    ctx.moveTo(px, top);
    ctx.lineTo(px, bottom);
    ctx.stroke();
    ctx.fillStyle = '#111827';
    ctx.textAlign = k === 0 ? 'left' : k === columns.length - 1 ? 'right' : 'center';
    const anchor = k === 0 ? px - 8 : k === columns.length - 1 ? px + 8 : px;
    ctx.font = `600 ${FONT}`;
    ctx.fillText(clipText(ctx, labels[k], Math.max(span - 8, 40)), anchor, 12);
    ctx.font = FONT;
    ctx.fillStyle = AXIS;
    const ticks = axes[k].labels;
    if (ticks) {
      ctx.textAlign = k === columns.length - 1 ? 'right' : 'left';
      for (const i of labelled(ticks)) {
        ctx.fillText(clipText(ctx, ticks[i], Math.max(span - 12, 30)), px + 4, y(k, i));
      }
      return;
    }
    ctx.fillText(formatNumber(ranges[k][1]), anchor, top - 10);
    ctx.fillText(formatNumber(ranges[k][0]), anchor, bottom + 11);
  });
  return { drawn: rows.length, total: complete.length, best };
}

/** Small scatter plots of each param in `names` against the score, early trials pale. */
function drawSlices(container, series, names, study) {
  const rows = series.complete;
  const wanted = names.join('\n');
  if (container.dataset.names !== wanted) {
    container.replaceChildren(
      ...names.map((name) => {
        const figure = document.createElement('figure');
        figure.className = 'slice';
        const caption = document.createElement('figcaption');
        caption.textContent = name;
        caption.title = name;
        figure.append(caption, document.createElement('canvas'));
        return figure;
      }),
    );
    container.dataset.names = wanted;
  }
  if (names.length === 0) {
    container.textContent = 'No numeric params vary yet';
    container.dataset.names = '';
    return;
  }
  const lastNumber = series.number.length ? series.number[series.number.length - 1] : 1;
  const [yLow, yHigh] = extent(rows.map((i) => series.value[i]));
  container.querySelectorAll('canvas').forEach((canvas, k) => {
    const { column, labels } = plotted(series, names[k], study);
    const { ctx, width, height } = prepare(canvas);
    const pad = { left: 44, right: 8, top: 6, bottom: 22 };
    const [xLow, xHigh] = labels ? [-0.5, labels.length - 0.5] : extent(rows.map((i) => column[i]));
    const x = (v) => pad.left + ((v - xLow) / (xHigh - xLow)) * (width - pad.left - pad.right);
    const y = (v) => height - pad.bottom - ((v - yLow) / (yHigh - yLow)) * (height - pad.top - pad.bottom);
    drawYAxis(ctx, pad.left, pad.top, height - pad.bottom, width - pad.right, yLow, yHigh, y);
    canvas.dataset.ticks = JSON.stringify(labels);
    if (labels) {
      ctx.strokeStyle = AXIS;
      ctx.beginPath();
      ctx.moveTo(pad.left, height - pad.bottom + 0.5);
      ctx.lineTo(width - pad.right, height - pad.bottom + 0.5);
      ctx.stroke();
      ctx.fillStyle = AXIS;
      ctx.textAlign = 'center';
      ctx.textBaseline = 'top';
      const room = (width - pad.left - pad.right) / labels.length;
      for (const i of labelled(labels)) {
        ctx.fillText(clipText(ctx, labels[i], Math.max(room - 4, 24)), x(i), height - pad.bottom + 6);
      }
    } else {
      drawXAxis(ctx, pad.left, width - pad.right, height - pad.bottom, xLow, xHigh, x, false);
    }
    const groups = PALETTE.map(() => []);
    for (const i of rows) {
      if (column[i] === null || column[i] === undefined) continue;
      groups[bucket(1 - series.number[i] / Math.max(lastNumber, 1))].push(i);
    }
    ctx.globalAlpha = 0.7;
    groups.forEach((group, b) => {
      ctx.fillStyle = PALETTE[b];
      for (const i of group) ctx.fillRect(x(column[i]) - 1.5, y(series.value[i]) - 1.5, 3, 3);
    });
    ctx.globalAlpha = 1;
  });
}

export class ParamsPanel {
  constructor(page) {
    this.page = page;
    this.tab = 'parallel';
    this.root = element(`<section class="card">
      <h2>Params and score</h2>
      <nav class="tabs" data-tabs>
        <button data-tab="parallel" class="active">Parallel coordinates</button>
        <button data-tab="slices">Slices</button>
        <button data-tab="correlation">Rank correlation</button>
        <button data-tab="importance">Importance</button>
        <button data-tab="contour">Contour</button>
      </nav>
      <p class="meta" data-params-note></p>
      <canvas class="chart tall" data-parallel></canvas>
      <div class="slices" data-slices hidden></div>
      <div class="correlation" data-correlation hidden></div>
      <div class="importance" data-importance hidden></div>
    </section>`);
    this.contour = new ContourView(page);
    this.root.append(this.contour.root);
    this.$ = finder(this.root);
    const tabs = this.$('tabs');
    tabs.addEventListener('click', (event) => {
      const button = event.target.closest('button[data-tab]');
      if (!button) return;
      this.tab = button.dataset.tab;
      for (const b of tabs.querySelectorAll('button')) b.classList.toggle('active', b === button);
      this.draw();
    });
    this.bindBrushing(this.$('parallel'));
  }

  /** Brushing an axis of the parallel coordinates (a vertical drag along it) filters
   * the trials to that range of it (or those choices); a click on an axis clears its
   * filter. The page's filters then redraw the panel and the trial table. */
  bindBrushing(canvas) {
    let start = null;
    const axisAt = (x) => canvas.axes?.list.find((axis) => Math.abs(axis.x - x) <= 12) ?? null;
    canvas.addEventListener('mousedown', (event) => {
      const axis = axisAt(event.offsetX);
      start = axis ? { axis, y: event.offsetY } : null;
      if (start) event.preventDefault();
    });
    canvas.addEventListener('mousemove', (event) => {
      canvas.style.cursor = start || axisAt(event.offsetX) ? 'ns-resize' : 'default';
    });
    window.addEventListener('mouseup', (event) => {
      if (!start) return;
      const { axis, y } = start;
      start = null;
      const box = canvas.getBoundingClientRect();
      const endY = event.clientY - box.top;
      const filters = this.page.filters;
      if (Math.abs(endY - y) < 3) {
        if (filters.ranges.has(axis.name)) filters.clear(axis.name);
        return;
      }
      const { top, bottom } = canvas.axes;
      const [lo, hi] = axis.range;
      const value = (py) => lo + ((bottom - Math.min(bottom, Math.max(top, py))) / (bottom - top)) * (hi - lo);
      const [low, high] = [value(Math.max(y, endY)), value(Math.min(y, endY))];
      if (axis.labels) {
        const choices = new Set(axis.labels.filter((_, index) => index >= low - 0.5 && index <= high + 0.5));
        if (choices.size) filters.set(axis.name, { choices });
        else filters.clear(axis.name);
      } else {
        filters.set(axis.name, { low, high });
      }
    });
  }

  /** The chart columns the panel draws: the searched params only (the page's
   * `searchedSeries`), and with filters on, the complete trials that pass them. */
  drawnSeries() {
    const { series, searchedSeries, filters } = this.page;
    const searched = searchedSeries ?? series;
    if (!filters.active) return searched;
    const complete = searched.complete.filter((i) => filters.passes(series, i));
    return Object.assign(Object.create(searched), { complete });
  }

  draw() {
    const { study, correlations, filters } = this.page;
    const everything = this.page.series;
    const series = this.page.searchedSeries ?? everything;
    const drawn = this.drawnSeries();
    const parallel = this.$('parallel');
    const slices = this.$('slices');
    const correlation = this.$('correlation');
    parallel.hidden = this.tab !== 'parallel';
    slices.hidden = this.tab !== 'slices';
    correlation.hidden = this.tab !== 'correlation';
    this.$('importance').hidden = this.tab !== 'importance';
    this.contour.root.hidden = this.tab !== 'contour';
    const names = correlations.map((c) => c.name);
    const shown = this.tab === 'slices' ? SLICE_PLOTS : PARALLEL_AXES;
    const notes = [];
    if (names.length > shown && (this.tab === 'parallel' || this.tab === 'slices')) {
      notes.push(`The ${shown} of ${names.length} varying params most rank-correlated with the score.`);
    }
    if (this.tab === 'parallel') {
      const axes = names.slice(0, PARALLEL_AXES);
      const lines = drawParallel(parallel, series, axes, study.direction, study, filters, everything);
      if (lines.drawn < lines.total) {
        notes.push(
          `Lines: the best ${lines.best.toLocaleString()} of ${lines.total.toLocaleString()} ` +
            `complete trials and an even sample of the rest (${lines.drawn.toLocaleString()} in all).`,
        );
      }
    } else if (this.tab === 'slices') {
      drawSlices(slices, drawn, names.slice(0, SLICE_PLOTS), study);
      notes.push('Colour: trial number, yellow early to purple late.');
    }
    if (filters.active) {
      const passing = drawn.complete.length;
      notes.push(
        `Filtered: ${passing} of ${series.complete.length} complete trials pass ` +
          `${filters.describe().map((f) => f.text).join(', ')}` +
          (this.tab === 'parallel' ? ' (the others grey; click a brushed axis to clear it).' : '.'),
      );
    } else if (this.tab === 'parallel') {
      notes.push('Drag along an axis to filter the trials to a range of it.');
    }
    this.$('params-note').textContent = notes.join(' ');
    if (this.tab === 'importance' || this.tab === 'contour') this.drawImportance(names);
    if (this.tab === 'correlation') {
      correlation.innerHTML = correlations.length
        ? correlations
            .map(
              (c) => `<div class="corr-row"><span class="name" title="${esc(c.name)}">${esc(c.name)}</span>
                <span class="corr-bar"><span class="${c.rho < 0 ? 'negative' : 'positive'}"
                  style="width:${(Math.abs(c.rho) * 100).toFixed(1)}%"></span></span>
                <span class="num">${c.rho.toFixed(2)}</span></div>`,
            )
            .join('') +
          '<p class="meta">Spearman rank correlation of each param with the score over complete trials.</p>'
        : '<p class="meta">Not enough complete trials yet.</p>';
    }
  }

  /** PED-ANOVA's ranking, shown as bars or used to pick the contour's two params (the
   * varying params most important first, then by rank correlation). */
  drawImportance(correlated) {
    const { series, study } = this.page;
    const result = pedAnova(series, study);
    if (this.tab === 'importance') {
      renderImportance(this.$('importance'), result, study);
      return;
    }
    const varying = varyingParams(series);
    const searched = (this.page.searchedSeries ?? series).params;
    const ranked = result.status === 'ok' ? result.importances.map((p) => p.name) : [];
    const order = [...new Set([...ranked, ...correlated, ...varying])].filter(
      (name) => varying.has(name) && name in searched,
    );
    this.contour.series = this.drawnSeries();
    this.contour.draw(order);
  }
}
