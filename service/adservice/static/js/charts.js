// What the hand-drawn canvas charts share: number format, palette, ranges, axes, and a
// canvas sized to its element. Each chart lives with its panel (history.js, params.js);
// the trial dialog's learning curve is here. Fast enough for 10,000 trials: points are
// batched by colour, so a redraw is a few dozen canvas calls plus one per point.

// Viridis in ten steps; index 9 is the best score.
export const PALETTE = [
  '#440154', '#482878', '#3e4989', '#31688e', '#26828e',
  '#1f9e89', '#35b779', '#6ece58', '#b5de2b', '#fde725',
];
export const AXIS = '#6b7280';
/** Trials that break a study's constraints, greyed out in every chart. */
export const INFEASIBLE = 'rgba(156, 163, 175, 0.55)';
const GRID = '#e5e7eb';
export const FONT = '11px system-ui, sans-serif';

/** A number as a person reads it: integers exactly (a train_steps of 12288 is 12288, not
 * 12290), others to 4 significant digits, tiny or huge ones in exponent form. */
export function formatNumber(value) {
  if (value === null || value === undefined || Number.isNaN(value)) return '—';
  if (typeof value !== 'number') return String(value);
  const magnitude = Math.abs(value);
  if (Number.isInteger(value) && magnitude < 1e15) return String(value);
  if (magnitude !== 0 && (magnitude >= 1e5 || magnitude < 1e-3)) return value.toExponential(2);
  return String(Number(value.toPrecision(4)));
}

/** About `count` round ticks over [low, high]: each a whole number of steps, rounded to
 * the step's own decimals (summing steps left float noise: 0 labelled -2.78e-17). */
export function niceTicks(low, high, count = 5) {
  if (!(high > low)) return [low];
  const rough = (high - low) / count;
  const magnitude = 10 ** Math.floor(Math.log10(rough));
  const ratio = rough / magnitude;
  const step = (ratio >= 7.5 ? 10 : ratio >= 3.5 ? 5 : ratio >= 1.5 ? 2 : 1) * magnitude;
  const decimals = Math.max(0, -Math.floor(Math.log10(step) + 1e-9));
  const round = (tick) =>
    decimals <= 100 ? Number(tick.toFixed(decimals)) : Number(tick.toPrecision(12));
  const ticks = [];
  for (let k = Math.ceil(low / step - 1e-9); k * step <= high + step * 1e-9; k++) {
    ticks.push(round(k * step) || 0); // never -0
  }
  return ticks;
}

/** Ticks of a log axis over exponents [low, high] (log10 of the values): the powers of
 * ten within it, or round values between where it spans less than two decades. */
export function logTicks(low, high) {
  const powers = niceTicks(low, high).filter((exponent) => Number.isInteger(exponent));
  if (powers.length >= 2) return powers.map((exponent) => Number(`1e${exponent}`));
  const values = niceTicks(10 ** low, 10 ** high, 4).filter((value) => value > 0);
  return values.length ? values : [10 ** low];
}

export function extent(values) {
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
export function prepare(canvas) {
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

/** `text` cut at its start with an ellipsis to fit `width` pixels. */
export function clipText(ctx, text, width) {
  if (ctx.measureText(text).width <= width) return text;
  let cut = text;
  while (cut.length > 1 && ctx.measureText(`…${cut}`).width > width) cut = cut.slice(1);
  return `…${cut}`;
}

const MAX_TICKS = 12;

/** Which tick indices of a categorical axis to label: all, or an even subset of many. */
export function labelled(labels) {
  const stride = Math.ceil(labels.length / MAX_TICKS);
  return labels.map((_, i) => i).filter((i) => i % stride === 0);
}

export function message(ctx, width, height, text) {
  ctx.fillStyle = AXIS;
  ctx.textAlign = 'center';
  ctx.textBaseline = 'middle';
  ctx.fillText(text, width / 2, height / 2);
}

/** Goodness in [0, 1] of each value by rank (1 = best), so colours follow the direction. */
export function goodness(values, direction) {
  const order = values.map((_, index) => index).sort((a, b) => values[a] - values[b]);
  const result = new Float64Array(values.length);
  const last = Math.max(values.length - 1, 1);
  order.forEach((index, rank) => {
    result[index] = direction === 'maximize' ? rank / last : 1 - rank / last;
  });
  return result;
}

export function bucket(good) {
  return Math.min(PALETTE.length - 1, Math.floor(good * PALETTE.length));
}

/** The y axis and its grid; with `log`, low and high are log10 of the range and `y`
 * takes a value (not its log). */
export function drawYAxis(ctx, left, top, bottom, right, low, high, y, { log = false } = {}) {
  ctx.strokeStyle = GRID;
  ctx.fillStyle = AXIS;
  ctx.textAlign = 'right';
  ctx.textBaseline = 'middle';
  ctx.lineWidth = 1;
  for (const tick of log ? logTicks(low, high) : niceTicks(low, high)) {
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

export function drawXAxis(ctx, left, right, bottom, low, high, x, integers) {
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
 * Hovering and clicking a chart's points: `nearest(x, y)` finds the point within reach
 * of the pointer (or null), `describe(point)` gives its tooltip's markup, and `open(point)`
 * is what a click on it does. With `flip`, the tooltip sits left of the pointer on the
 * chart's right half, so the card does not cut it off. `clickable(point)` says whether a
 * point opens anything (all do unless it says otherwise).
 */
export function bindPoints(canvas, tooltip, { nearest, describe, open, flip = false, clickable = () => true }) {
  canvas.addEventListener('mousemove', (event) => {
    const point = nearest(event.offsetX, event.offsetY);
    canvas.style.cursor = point && clickable(point) ? 'pointer' : 'default';
    if (!point) {
      tooltip.hidden = true;
      return;
    }
    tooltip.hidden = false;
    tooltip.innerHTML = describe(point);
    const leftward = flip && event.offsetX > canvas.clientWidth / 2;
    tooltip.style.left = leftward ? 'auto' : `${event.offsetX + 12}px`;
    tooltip.style.right = leftward ? `${canvas.clientWidth - event.offsetX + 12}px` : 'auto';
    tooltip.style.top = `${event.offsetY - 8}px`;
  });
  canvas.addEventListener('mouseleave', () => {
    tooltip.hidden = true;
  });
  canvas.addEventListener('click', (event) => {
    const point = nearest(event.offsetX, event.offsetY);
    if (point && clickable(point)) open(point);
  });
}

const isNumber = (v) => typeof v === 'number' && Number.isFinite(v);

/**
 * The points of a trial's curve.json: its training points ({x: steps, y: score}) and its
 * evaluation episodes ({x, y: score, seed}), marked at the steps trained before them.
 * The contract is adclient.schemas.Curve ({train: [{steps, score}], evaluation: [{seed,
 * score, ...}], train_steps}); a file of another shape a --function job uploaded (a list
 * of numbers, or an object of number arrays such as {steps, y}) is its training points.
 */
export function curvePoints(curve) {
  if (curve && typeof curve === 'object' && (Array.isArray(curve.train) || Array.isArray(curve.evaluation))) {
    const train = (curve.train ?? [])
      .filter((p) => isNumber(p?.steps) && isNumber(p?.score))
      .map((p) => ({ x: p.steps, y: p.score }));
    const at = isNumber(curve.train_steps) ? curve.train_steps : (train.at(-1)?.x ?? 0);
    const evaluation = (curve.evaluation ?? [])
      .filter((e) => isNumber(e?.score))
      .map((e) => ({ x: at, y: e.score, seed: e.seed }));
    return { train, evaluation };
  }
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
  if (!ys || !ys.every(isNumber)) return { train: [], evaluation: [] };
  if (!xs || xs.length !== ys.length || !xs.every(isNumber)) xs = ys.map((_, i) => i);
  return { train: ys.map((y, i) => ({ x: xs[i], y })), evaluation: [] };
}

const EVALUATION = '#ea580c';

/**
 * A small chart of a trial's learning curve (curve.json): the training score against
 * steps as a line, each evaluation episode's score a dot at the steps trained. Leaves
 * `data-train-points` and `data-evaluation-points` (what it drew) for the browser tests.
 */
export function drawCurve(canvas, curve) {
  const { ctx, width, height } = prepare(canvas);
  const { train, evaluation } = curvePoints(curve);
  canvas.dataset.trainPoints = String(train.length);
  canvas.dataset.evaluationPoints = String(evaluation.length);
  const all = [...train, ...evaluation];
  if (all.length === 0) {
    message(ctx, width, height, 'curve.json has no numbers to plot');
    return false;
  }
  const pad = { left: 50, right: 12, top: 8, bottom: 22 };
  const [xLow, xHigh] = extent(all.map((p) => p.x));
  const [yLow, yHigh] = extent(all.map((p) => p.y));
  const x = (v) => pad.left + ((v - xLow) / (xHigh - xLow)) * (width - pad.left - pad.right);
  const y = (v) => height - pad.bottom - ((v - yLow) / (yHigh - yLow)) * (height - pad.top - pad.bottom);
  drawYAxis(ctx, pad.left, pad.top, height - pad.bottom, width - pad.right, yLow, yHigh, y);
  drawXAxis(ctx, pad.left, width - pad.right, height - pad.bottom, xLow, xHigh, x, false);
  ctx.strokeStyle = '#2563eb';
  ctx.fillStyle = '#2563eb';
  ctx.lineWidth = 1.5;
  ctx.beginPath();
  train.forEach((p, i) => (i ? ctx.lineTo(x(p.x), y(p.y)) : ctx.moveTo(x(p.x), y(p.y))));
  ctx.stroke();
  if (train.length === 1) {
    ctx.beginPath();
    ctx.arc(x(train[0].x), y(train[0].y), 2.5, 0, 2 * Math.PI);
    ctx.fill();
  }
  ctx.fillStyle = EVALUATION;
  for (const p of evaluation) {
    ctx.beginPath();
    ctx.arc(x(p.x), y(p.y), 3.5, 0, 2 * Math.PI);
    ctx.fill();
  }
  return true;
}
