// Parameter importance by PED-ANOVA (Watanabe et al., IJCAI 2023; Optuna's default
// importance evaluator since Optuna 5, PedAnovaImportanceEvaluator with its defaults):
// for each param, the Pearson divergence between the param's distribution among the
// top-γ quantile of complete trials (γ = 0.1, at least 2 trials) and among all of them,
// each a 1-D Parzen estimate on a grid over the param's own scale (a log param on a log
// scale, an int or stepped one on its grid, at most 50 points; a categorical one a
// smoothed histogram of its choices), normalised to sum to 1.
//
// Why PED-ANOVA rather than fANOVA: it needs no random forest, so it runs in the page in
// time linear in the trials and says something from tens of trials, and it measures
// what matters to reach the good region (the top 10%) rather than how the score varies
// over the whole space, which is what someone tuning a study asks.
//
// Computed in the page from the chart columns the study page already holds (series.js);
// the score is the one the other charts draw (a study of several objectives: its first
// objective, in that objective's direction). A trial that breaks the study's constraints
// ranks behind every feasible one, so it is never among the top trials unless too few
// are feasible. A param a trial lacks leaves that trial out of the param's estimates, and
// the param's divergence is weighted by how many of the trials have it (Optuna 5's
// conditional PED-ANOVA with one regime).

import { element, esc } from './html.js';
import { isChoices } from './series.js';

export const QUANTILE = 0.1;
const MIN_TOP = 2;
/** Fewer complete trials than this and the panel says so instead of drawing. */
export const MIN_TRIALS = 10;
const GRID = 50;
const PRIOR = 1;
const SIGMA_MIN = 0.5 / 1.64;
const TINY = 1e-12;

/**
 * What a param is, for estimating its distribution and for plotting it: categorical
 * (its choices as `labels`, each trial's choice as an index in `codes`), or numeric
 * (`low`, `high`, `log`, `step`, `int`, the values in `values`). Bounds and kinds come
 * from the study's box space where it names the param, else from the values themselves
 * over `rows` (a design study's spec names: linear, between the least and greatest).
 */
export function paramDomain(series, name, study, rows) {
  const column = series.params[name];
  const spec = study.space?.params?.find?.((param) => param.name === name);
  if (spec?.type === 'categorical' || (!spec && isChoices(column))) {
    const observed = rows.map((i) => column[i]).filter((v) => v !== null && v !== undefined);
    const seen = spec?.choices ?? [...new Set(observed)];
    const index = new Map(seen.map((choice, i) => [choice, i]));
    return {
      name,
      kind: 'categorical',
      labels: seen.map(String),
      codes: column.map((value) => index.get(value) ?? null),
    };
  }
  let low = Infinity;
  let high = -Infinity;
  for (const i of rows) {
    const value = column[i];
    if (typeof value !== 'number') continue;
    if (value < low) low = value;
    if (value > high) high = value;
  }
  const int = spec?.type === 'int';
  if (spec && typeof spec.low === 'number' && typeof spec.high === 'number') {
    low = Math.min(low, spec.low);
    high = Math.max(high, spec.high);
  }
  return {
    name,
    kind: 'numeric',
    low,
    high,
    log: Boolean(spec?.log) && low > 0,
    step: spec?.step ?? (int ? 1 : null),
    int,
    values: column.map((value) => (typeof value === 'number' ? value : null)),
  };
}

/** The grid a numeric param is counted on: how many points, and a value's index. */
function numericGrid(domain) {
  const { low, high, log, step, int } = domain;
  let size = GRID;
  if (int && log) size = Math.min(Math.ceil(Math.log2(high - low + 1)) + 1, GRID);
  else if (step) size = Math.min(Math.round((high - low) / step) + 1, GRID);
  const scale = log ? Math.log : (v) => v;
  const lo = scale(low);
  const width = (scale(high) - lo) / (size - 1);
  const index = (value) => Math.min(size - 1, Math.max(0, Math.ceil((scale(value) - lo) / width - 0.5)));
  return { size, index };
}

const ERFC = [
  -1.26551223, 1.00002368, 0.37409196, 0.09678418, -0.18628806, 0.27886807, -1.13520398, 1.48851587,
  -0.82215223, 0.17087277,
];

/** erfc(x), fractional error below 1.2e-7 everywhere (Numerical Recipes' erfcc). */
function erfc(x) {
  const z = Math.abs(x);
  const t = 1 / (1 + 0.5 * z);
  let poly = 0;
  for (let k = ERFC.length - 1; k >= 0; k--) poly = ERFC[k] + t * poly;
  const value = t * Math.exp(-z * z + poly);
  return x >= 0 ? value : 2 - value;
}

/** A standard normal's mass below and above z, the smaller to full relative precision. */
function tails(z) {
  const far = erfc(Math.abs(z) / Math.SQRT2) / 2;
  return z < 0 ? [far, 1 - far] : [1 - far, far];
}

/** A standard normal's mass between a and b (a < b), without cancelling in a tail. */
function mass([belowA, aboveA], [belowB, aboveB], a, b) {
  if (a >= 0) return aboveA - aboveB;
  if (b <= 0) return belowB - belowA;
  return 1 - belowA - aboveB;
}

/**
 * The Parzen estimate on grid points 0..size-1 of a numeric param counted there
 * (`counts`): a discrete normal kernel, truncated to the grid, at each point with
 * trials, weighted by their count, its width by Scott's rule (never under 0.5/1.64 of a
 * step), and a wide prior kernel at the middle of weight 1. Returns the probabilities.
 */
function numericDensity(counts) {
  const size = counts.length;
  const points = [];
  const weights = [];
  counts.forEach((count, j) => {
    if (count > 0) {
      points.push(j);
      weights.push(count);
    }
  });
  const total = weights.reduce((a, b) => a + b, 0);
  let mean = 0;
  points.forEach((p, k) => (mean += p * weights[k]));
  mean /= total;
  let spread = 0;
  points.forEach((p, k) => (spread += (p - mean) ** 2 * weights[k]));
  spread = Math.sqrt(spread / Math.max(1, total - 1));
  const cumulative = [];
  weights.reduce((sum, w, k) => (cumulative[k] = sum + w), 0);
  const q1 = cumulative.findIndex((c) => c >= Math.floor(total / 4));
  let q3 = cumulative.findIndex((c) => c > Math.floor((total * 3) / 4));
  if (q3 < 0) q3 = points.length - 1;
  const iqr = points[Math.min(points.length - 1, q3)] - points[q1];
  const sigma = Math.max(1.059 * Math.min(iqr / 1.34, spread) * total ** -0.2, SIGMA_MIN);
  const kernels = points.map((p, k) => [p, sigma, weights[k] / (total + PRIOR)]);
  kernels.push([(size - 1) / 2, size, PRIOR / (total + PRIOR)]);
  const density = new Float64Array(size);
  for (const [mu, s, weight] of kernels) {
    // The kernel's mass over each grid point's cell [j - 1/2, j + 1/2], over its mass
    // over the whole grid: each cell edge's normal tails are found once.
    const edges = [];
    for (let j = 0; j <= size; j++) edges.push((j - 0.5 - mu) / s);
    const edgeTails = edges.map(tails);
    const whole = mass(edgeTails[0], edgeTails[size], edges[0], edges[size]);
    for (let j = 0; j < size; j++) {
      density[j] += (weight * mass(edgeTails[j], edgeTails[j + 1], edges[j], edges[j + 1])) / whole;
    }
  }
  return density;
}

/**
 * The smoothed histogram of a categorical param's `counts` over its choices: each
 * observed choice a kernel that puts most of its mass on that choice and the prior's
 * share evenly on all, weighted by its count, plus a uniform prior of weight 1.
 */
function categoricalDensity(counts) {
  const n = counts.length;
  const total = counts.reduce((a, b) => a + b, 0);
  const kernels = counts.filter((c) => c > 0).length + 1;
  const share = PRIOR / kernels;
  return Float64Array.from(
    counts,
    (count) => ((total * share + count) / (n * share + 1) + PRIOR / n) / (total + PRIOR),
  );
}

/** How far the top trials' distribution is from all trials': Σ p_all (p_top / p_all - 1)². */
function pearsonDivergence(top, all) {
  let divergence = 0;
  for (let j = 0; j < top.length; j++) {
    const local = all[j] + TINY;
    divergence += local * ((top[j] + TINY) / local - 1) ** 2;
  }
  return divergence;
}

/** The rows of `rows` whose score is in the top `quantile` (at least MIN_TOP; ties kept). */
function topRows(series, rows, direction) {
  const sign = direction === 'maximize' ? -1 : 1;
  const loss = new Map(
    rows.map((i) => [i, series.feasible?.[i] === false ? Infinity : sign * series.value[i]]),
  );
  const sorted = [...loss.values()].sort((a, b) => a - b);
  const wanted = Math.max(MIN_TOP, Math.ceil(QUANTILE * rows.length));
  const cutoff = sorted[Math.min(wanted, sorted.length) - 1];
  return rows.filter((i) => loss.get(i) <= cutoff);
}

/** A param's importance before normalising (0 for a param of one value). */
function divergenceOf(domain, rows, top) {
  const codes = domain.kind === 'categorical' ? domain.codes : domain.values;
  const present = rows.filter((i) => codes[i] !== null && codes[i] !== undefined);
  const topPresent = top.filter((i) => codes[i] !== null && codes[i] !== undefined);
  if (present.length < MIN_TOP || topPresent.length === 0) return 0;
  let size;
  let at;
  let density;
  if (domain.kind === 'categorical') {
    size = domain.labels.length;
    at = (i) => codes[i];
    density = categoricalDensity;
  } else {
    const grid = numericGrid(domain);
    size = grid.size;
    at = (i) => grid.index(codes[i]);
    density = numericDensity;
  }
  const count = (which) => {
    const counts = new Array(size).fill(0);
    for (const i of which) counts[at(i)] += 1;
    return counts;
  };
  const alpha = topPresent.length / top.length;
  const beta = present.length / rows.length;
  return ((alpha * alpha) / beta) * pearsonDivergence(density(count(topPresent)), density(count(present)));
}

/** The params with at least two values among the complete trials. */
export function varyingParams(series) {
  const varying = new Set();
  for (const [name, column] of Object.entries(series.params)) {
    const values = new Set();
    for (const i of series.complete) {
      if (column[i] !== null && column[i] !== undefined) values.add(column[i]);
      if (values.size > 1) {
        varying.add(name);
        break;
      }
    }
  }
  return varying;
}

/** The score the charts draw and the direction it is better in. */
export function scoreDirection(study) {
  return study.directions?.[0] ?? study.direction;
}

/**
 * PED-ANOVA importances of the study's params over its complete trials. Returns
 * `{status, trials, top, importances, fixed}`: status 'few' (under MIN_TRIALS complete
 * trials), 'flat' (every trial ties for the top, or no param's distribution differs
 * there) or 'ok'; importances `[{name, importance}]` of the params that vary, highest
 * first, summing to 1 when 'ok'; `fixed` the names of those of one value (importance 0).
 */
export function pedAnova(series, study) {
  const rows = series.complete;
  const varying = varyingParams(series);
  const names = Object.keys(series.params).filter((name) => varying.has(name));
  const fixed = Object.keys(series.params).filter((name) => !varying.has(name));
  const result = { status: 'ok', trials: rows.length, top: 0, importances: [], fixed };
  if (rows.length < MIN_TRIALS) return { ...result, status: 'few' };
  const top = topRows(series, rows, scoreDirection(study));
  result.top = top.length;
  const raw = names.map((name) => ({
    name,
    importance: top.length < rows.length ? divergenceOf(paramDomain(series, name, study, rows), rows, top) : 0,
  }));
  const total = raw.reduce((sum, p) => sum + p.importance, 0);
  if (!(total > 0)) return { ...result, status: 'flat', importances: raw };
  result.importances = raw
    .map((p) => ({ name: p.name, importance: p.importance / total }))
    .sort((a, b) => b.importance - a.importance || a.name.localeCompare(b.name));
  return result;
}

/** The importance view's markup: a sorted bar per param, or why there is none. */
export function renderImportance(container, result, study) {
  const objective = (study.objective_names?.length ?? 0) > 1 ? ` of ${esc(study.objective_names[0])}` : '';
  const better = scoreDirection(study) === 'maximize' ? 'highest' : 'lowest';
  container.dataset.status = result.status;
  container.dataset.importances = JSON.stringify(
    Object.fromEntries([
      ...result.importances.map((p) => [p.name, p.importance]),
      ...result.fixed.map((name) => [name, 0]),
    ]),
  );
  const head = element(`<p class="meta" data-importance-method><strong>PED-ANOVA, top
    ${Math.round(QUANTILE * 100)}%</strong>: the ${result.top} complete trials with the ${better}
    score${objective} of ${result.trials}, against all of them.</p>`);
  const why = element(`<p class="meta" data-importance-why>Each param's importance is how far its
    distribution among the top trials is from its distribution among all (Pearson divergence of
    1-D Parzen estimates), normalised to sum to 1. PED-ANOVA (Optuna's default since v5) rather
    than fANOVA: it works from tens of trials, costs time linear in the trials, and is local to the
    good region, what a study's params need to reach it rather than how they move the score
    everywhere.</p>`);
  if (result.status !== 'ok') {
    const text =
      result.status === 'few'
        ? `Parameter importance (PED-ANOVA) needs at least ${MIN_TRIALS} complete trials; ` +
          `this study has ${result.trials}.`
        : 'No param stands out: the top trials are spread as all trials are (or every trial ties).';
    container.replaceChildren(element(`<p class="meta" data-importance-message>${esc(text)}</p>`));
    return;
  }
  const largest = result.importances[0].importance;
  const rows = result.importances.map((p) => {
    const width = ((p.importance / largest) * 100).toFixed(1);
    return element(`<div class="importance-row" data-param="${esc(p.name)}">
      <span class="name" title="${esc(p.name)}">${esc(p.name)}</span>
      <span class="corr-bar"><span class="positive" style="width:${width}%"></span></span>
      <span class="num">${p.importance.toFixed(3)}</span></div>`);
  });
  const fixed = result.fixed.length
    ? [
        element(`<p class="meta" data-importance-fixed>One value in every complete trial (importance 0):
          ${result.fixed.map(esc).join(', ')}.</p>`),
      ]
    : [];
  container.replaceChildren(head, ...rows, ...fixed, why);
}
