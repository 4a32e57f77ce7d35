// Canvas charts drawn by hand: score history with the best-so-far curve, parallel
// coordinates, slice plots and a rank-correlation list. Fast enough for 10,000 trials:
// points are batched by colour, so a redraw is a few dozen canvas calls plus one per point.

// Viridis in ten steps; index 9 is the best score.
export const PALETTE = [
  '#440154', '#482878', '#3e4989', '#31688e', '#26828e',
  '#1f9e89', '#35b779', '#6ece58', '#b5de2b', '#fde725',
];
const AXIS = '#6b7280';
const GRID = '#e5e7eb';
const FONT = '11px system-ui, sans-serif';

export function formatNumber(value) {
  if (value === null || value === undefined || Number.isNaN(value)) return '—';
  if (typeof value !== 'number') return String(value);
  const magnitude = Math.abs(value);
  if (magnitude !== 0 && (magnitude >= 1e5 || magnitude < 1e-3)) return value.toExponential(2);
  return String(Number(value.toPrecision(4)));
}

function niceTicks(low, high, count = 5) {
  if (!(high > low)) return [low];
  const rough = (high - low) / count;
  const magnitude = 10 ** Math.floor(Math.log10(rough));
  const ratio = rough / magnitude;
  const step = (ratio >= 7.5 ? 10 : ratio >= 3.5 ? 5 : ratio >= 1.5 ? 2 : 1) * magnitude;
  const ticks = [];
  for (let tick = Math.ceil(low / step) * step; tick <= high + step * 1e-9; tick += step) {
    ticks.push(Number(tick.toPrecision(12)));
  }
  return ticks;
}

function extent(values) {
  let low = Infinity;
  let high = -Infinity;
  for (const value of values) {
    if (value === null || value === undefined) continue;
    if (value < low) low = value;
    if (value > high) high = value;
  }
  if (low === Infinity) return [0, 1];
  if (low === high) return [low - 0.5, high + 0.5];
  const margin = (high - low) * 0.05;
  return [low - margin, high + margin];
}

/** Size the backing store to the element (sharp on high-DPI screens) and clear it. */
function prepare(canvas) {
  const ratio = window.devicePixelRatio || 1;
  const width = canvas.clientWidth;
  const height = canvas.clientHeight;
  if (canvas.width !== Math.round(width * ratio) || canvas.height !== Math.round(height * ratio)) {
    canvas.width = Math.round(width * ratio);
    canvas.height = Math.round(height * ratio);
  }
  const ctx = canvas.getContext('2d');
  ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
  ctx.clearRect(0, 0, width, height);
  ctx.font = FONT;
  return { ctx, width, height };
}

function message(ctx, width, height, text) {
  ctx.fillStyle = AXIS;
  ctx.textAlign = 'center';
  ctx.textBaseline = 'middle';
  ctx.fillText(text, width / 2, height / 2);
}

/** Goodness in [0, 1] of each value by rank (1 = best), so colours follow the direction. */
function goodness(values, direction) {
  const order = values.map((_, index) => index).sort((a, b) => values[a] - values[b]);
  const result = new Float64Array(values.length);
  const last = Math.max(values.length - 1, 1);
  order.forEach((index, rank) => {
    result[index] = direction === 'maximize' ? rank / last : 1 - rank / last;
  });
  return result;
}

function bucket(good) {
  return Math.min(PALETTE.length - 1, Math.floor(good * PALETTE.length));
}

function drawYAxis(ctx, left, top, bottom, right, low, high, y) {
  ctx.strokeStyle = GRID;
  ctx.fillStyle = AXIS;
  ctx.textAlign = 'right';
  ctx.textBaseline = 'middle';
  ctx.lineWidth = 1;
  for (const tick of niceTicks(low, high)) {
    const py = Math.round(y(tick)) + 0.5;
    ctx.beginPath();
    ctx.moveTo(left, py);
    ctx.lineTo(right, py);
    ctx.stroke();
    ctx.fillText(formatNumber(tick), left - 6, py);
  }
  ctx.strokeStyle = AXIS;
  ctx.beginPath();
  ctx.moveTo(left + 0.5, top);
  ctx.lineTo(left + 0.5, bottom);
  ctx.stroke();
}

function drawXAxis(ctx, left, right, bottom, low, high, x, integers) {
  ctx.strokeStyle = AXIS;
  ctx.fillStyle = AXIS;
  ctx.textAlign = 'center';
  ctx.textBaseline = 'top';
  ctx.beginPath();
  ctx.moveTo(left, bottom + 0.5);
  ctx.lineTo(right, bottom + 0.5);
  ctx.stroke();
  for (const tick of niceTicks(low, high, Math.max(2, Math.floor((right - left) / 80)))) {
    if (integers && !Number.isInteger(tick)) continue;
    const px = Math.round(x(tick)) + 0.5;
    ctx.beginPath();
    ctx.moveTo(px, bottom);
    ctx.lineTo(px, bottom + 4);
    ctx.stroke();
    ctx.fillText(formatNumber(tick), px, bottom + 6);
  }
}

/**
 * Every complete trial's score against its number, the best-so-far curve over them,
 * and ticks for failed (red) and unfinished (grey) trials along the bottom.
 * Leaves on the canvas what hovering needs (`canvas.hit`), and `data-points`,
 * `data-failed` and `data-best` (the curve's last value) for tests.
 */
export function drawHistory(canvas, series, direction) {
  const { ctx, width, height } = prepare(canvas);
  const pad = { left: 58, right: 14, top: 10, bottom: 28 };
  const numbers = [];
  const values = [];
  const failed = [];
  const open = [];
  for (let i = 0; i < series.number.length; i++) {
    const state = series.state[i];
    if (state === 'complete' && series.value[i] !== null) {
      numbers.push(series.number[i]);
      values.push(series.value[i]);
    } else if (state === 'failed') failed.push(series.number[i]);
    else open.push(series.number[i]);
  }
  canvas.dataset.points = String(values.length);
  canvas.dataset.failed = String(failed.length);
  canvas.dataset.best = '';
  canvas.hit = null;
  if (series.number.length === 0) {
    message(ctx, width, height, 'No trials yet');
    return;
  }
  const lastNumber = series.number[series.number.length - 1];
  const xHigh = Math.max(lastNumber, 1);
  const [yLow, yHigh] = extent(values);
  const left = pad.left;
  const right = width - pad.right;
  const top = pad.top;
  const bottom = height - pad.bottom;
  const x = (n) => left + ((n - 0) / (xHigh - 0 || 1)) * (right - left);
  const y = (v) => bottom - ((v - yLow) / (yHigh - yLow)) * (bottom - top);

  drawYAxis(ctx, left, top, bottom, right, yLow, yHigh, y);
  drawXAxis(ctx, left, right, bottom, 0, xHigh, x, true);

  ctx.fillStyle = 'rgba(37, 99, 235, 0.5)';
  const size = values.length > 2000 ? 2 : 4;
  for (let i = 0; i < values.length; i++) {
    ctx.fillRect(x(numbers[i]) - size / 2, y(values[i]) - size / 2, size, size);
  }
  ctx.fillStyle = 'rgba(220, 38, 38, 0.8)';
  for (const n of failed) ctx.fillRect(x(n) - 0.75, bottom - 7, 1.5, 7);
  ctx.fillStyle = 'rgba(107, 114, 128, 0.6)';
  for (const n of open) ctx.fillRect(x(n) - 0.75, bottom - 4, 1.5, 4);

  if (values.length > 0) {
    const better = direction === 'maximize' ? (a, b) => a > b : (a, b) => a < b;
    let best = values[0];
    ctx.strokeStyle = '#ea580c';
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.moveTo(x(numbers[0]), y(best));
    for (let i = 1; i < values.length; i++) {
      if (better(values[i], best)) {
        ctx.lineTo(x(numbers[i]), y(best));
        best = values[i];
        ctx.lineTo(x(numbers[i]), y(best));
      }
    }
    ctx.lineTo(x(lastNumber), y(best));
    ctx.stroke();
    ctx.lineWidth = 1;
    canvas.dataset.best = String(best);
  }
  canvas.hit = { numbers, values, x, y };
}

/** The complete trial nearest the pointer (within 12 px), as {number, value}. */
export function nearestPoint(canvas, offsetX, offsetY) {
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
      best = { number: hit.numbers[i], value: hit.values[i] };
    }
  }
  return best;
}

/** Complete trials' scores and the numeric values of `names`, nulls kept. */
export function completeRows(series) {
  const rows = [];
  for (let i = 0; i < series.number.length; i++) {
    if (series.state[i] === 'complete' && series.value[i] !== null) rows.push(i);
  }
  return rows;
}

function ranks(values) {
  const order = values.map((_, index) => index).sort((a, b) => values[a] - values[b]);
  const result = new Float64Array(values.length);
  order.forEach((index, rank) => {
    result[index] = rank;
  });
  return result;
}

function pearson(a, b) {
  const n = a.length;
  let ma = 0;
  let mb = 0;
  for (let i = 0; i < n; i++) {
    ma += a[i];
    mb += b[i];
  }
  ma /= n;
  mb /= n;
  let sab = 0;
  let saa = 0;
  let sbb = 0;
  for (let i = 0; i < n; i++) {
    sab += (a[i] - ma) * (b[i] - mb);
    saa += (a[i] - ma) ** 2;
    sbb += (b[i] - mb) ** 2;
  }
  return saa > 0 && sbb > 0 ? sab / Math.sqrt(saa * sbb) : 0;
}

/**
 * Spearman rank correlation of each varying numeric param with the score over complete
 * trials, strongest first: a cheap guide to which params matter (not a causal importance).
 */
export function paramCorrelations(series) {
  const rows = completeRows(series);
  const result = [];
  for (const [name, column] of Object.entries(series.params)) {
    const xs = [];
    const ys = [];
    for (const i of rows) {
      if (column[i] !== null && column[i] !== undefined) {
        xs.push(column[i]);
        ys.push(series.value[i]);
      }
    }
    let [low, high] = [Infinity, -Infinity];
    for (const value of xs) {
      if (value < low) low = value;
      if (value > high) high = value;
    }
    if (xs.length < 2 || !(high > low)) continue;
    result.push({ name, rho: xs.length >= 3 ? pearson(ranks(xs), ranks(ys)) : 0, n: xs.length });
  }
  result.sort((a, b) => Math.abs(b.rho) - Math.abs(a.rho) || a.name.localeCompare(b.name));
  return result;
}

function clipText(ctx, text, width) {
  if (ctx.measureText(text).width <= width) return text;
  let cut = text;
  while (cut.length > 1 && ctx.measureText(`…${cut}`).width > width) cut = cut.slice(1);
  return `…${cut}`;
}

export const MAX_LINES = 2500;

/**
 * Polylines across the axes `names` and the score, coloured by rank of score (yellow =
 * best), drawn worst first so the best lie on top. Past MAX_LINES complete trials it
 * draws the best half of that many and an even sample of the rest (rasterising
 * thousands of translucent lines is what costs), and says so in its return value.
 */
export function drawParallel(canvas, series, names, direction) {
  const { ctx, width, height } = prepare(canvas);
  const complete = completeRows(series);
  canvas.dataset.lines = String(complete.length);
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
  const columns = [...names.map((name) => series.params[name]), series.value];
  const labels = [...names, 'score'];
  const ranges = columns.map((column) => extent(rows.map((i) => column[i])));
  const span = (width - pad.left - pad.right) / Math.max(columns.length - 1, 1);
  const axisX = columns.map((_, k) => pad.left + k * span);
  const top = pad.top;
  const bottom = height - pad.bottom;
  const y = (k, v) => bottom - ((v - ranges[k][0]) / (ranges[k][1] - ranges[k][0])) * (bottom - top);

  const good = kept ? kept.map((r) => allGood[r]) : allGood;
  const paths = PALETTE.map(() => new Path2D());
  rows.forEach((i, r) => {
    const path = paths[bucket(good[r])];
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
  ctx.globalAlpha = rows.length <= 50 ? 0.85 : Math.max(0.06, 6 / Math.sqrt(rows.length));
  ctx.lineWidth = 1;
  paths.forEach((path, b) => {
    ctx.strokeStyle = PALETTE[b];
    ctx.stroke(path);
  });
  ctx.globalAlpha = 1;

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
    ctx.fillText(formatNumber(ranges[k][1]), anchor, top - 10);
    ctx.fillText(formatNumber(ranges[k][0]), anchor, bottom + 11);
  });
  return { drawn: rows.length, total: complete.length, best };
}

/** Small scatter plots of each param in `names` against the score, early trials pale. */
export function drawSlices(container, series, names) {
  const rows = completeRows(series);
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
    const column = series.params[names[k]];
    const { ctx, width, height } = prepare(canvas);
    const pad = { left: 44, right: 8, top: 6, bottom: 22 };
    const [xLow, xHigh] = extent(rows.map((i) => column[i]));
    const x = (v) => pad.left + ((v - xLow) / (xHigh - xLow)) * (width - pad.left - pad.right);
    const y = (v) => height - pad.bottom - ((v - yLow) / (yHigh - yLow)) * (height - pad.top - pad.bottom);
    drawYAxis(ctx, pad.left, pad.top, height - pad.bottom, width - pad.right, yLow, yHigh, y);
    drawXAxis(ctx, pad.left, width - pad.right, height - pad.bottom, xLow, xHigh, x, false);
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

/** A small line chart of a worker's learning curve (curve.json): numbers, or {x, y}. */
export function drawCurve(canvas, curve) {
  const { ctx, width, height } = prepare(canvas);
  let ys = Array.isArray(curve) ? curve : null;
  let xs = null;
  if (!ys && curve && typeof curve === 'object') {
    const arrays = Object.entries(curve).filter(
      ([, value]) => Array.isArray(value) && value.every((v) => typeof v === 'number'),
    );
    const named = Object.fromEntries(arrays);
    ys = named.y ?? named.returns ?? named.reward ?? named.rewards ?? arrays.at(-1)?.[1] ?? null;
    xs = named.x ?? named.steps ?? named.timesteps ?? null;
  }
  if (!ys || ys.length === 0 || !ys.every((v) => typeof v === 'number')) {
    message(ctx, width, height, 'curve.json has no numbers to plot');
    return false;
  }
  if (!xs || xs.length !== ys.length) xs = ys.map((_, i) => i);
  const pad = { left: 50, right: 10, top: 8, bottom: 22 };
  const [xLow, xHigh] = extent(xs);
  const [yLow, yHigh] = extent(ys);
  const x = (v) => pad.left + ((v - xLow) / (xHigh - xLow)) * (width - pad.left - pad.right);
  const y = (v) => height - pad.bottom - ((v - yLow) / (yHigh - yLow)) * (height - pad.top - pad.bottom);
  drawYAxis(ctx, pad.left, pad.top, height - pad.bottom, width - pad.right, yLow, yHigh, y);
  drawXAxis(ctx, pad.left, width - pad.right, height - pad.bottom, xLow, xHigh, x, false);
  ctx.strokeStyle = '#2563eb';
  ctx.lineWidth = 1.5;
  ctx.beginPath();
  ys.forEach((v, i) => (i ? ctx.lineTo(x(xs[i]), y(v)) : ctx.moveTo(x(xs[i]), y(v))));
  ctx.stroke();
  return true;
}
