// A study's chart columns (number, state, value, params, and for a study of several
// objectives or with constraints its values and feasible), kept current by deltas: the
// first load reads them all, a poll only the new trials and those last seen open. The
// rows the charts draw (complete trials with a score) are found once per load, here.
// A study of several objectives has no single value: its score, as the score charts
// draw it, is its first objective.

import { getJSON } from './api.js';

/** Row indices of the complete trials that have a score. */
function completeRows(series) {
  const rows = [];
  for (let i = 0; i < series.number.length; i++) {
    if (series.state[i] === 'complete' && series.value[i] !== null) rows.push(i);
  }
  return rows;
}

export class Series {
  constructor(studyId) {
    this.url = `/api/v1/dashboard/studies/${studyId}/series`;
    this.loaded = false;
    this.number = [];
    this.state = [];
    this.value = [];
    /** Each trial's objective values (a study of several objectives), else null. */
    this.values = null;
    /** Whether each trial meets the study's constraints (a study with some), else null. */
    this.feasible = null;
    this.params = {};
    this.index = new Map();
    /** Row indices of the complete trials with a score, in trial order. */
    this.complete = [];
  }

  /** Everything the first time, then a delta: new trials and the ones last seen open. */
  async load() {
    if (!this.loaded) {
      const [first, ...rest] = await this.pages(this.url);
      this.setColumns(first);
      rest.forEach((page) => this.merge(page));
      this.loaded = true;
    } else {
      const open = [];
      for (let i = 0; i < this.number.length; i++) {
        if (this.state[i] === 'queued' || this.state[i] === 'running') open.push(this.number[i]);
      }
      let after = this.number.length ? this.number[this.number.length - 1] + 1 : 0;
      let numbers = open;
      if (open.length > 500) {
        after = Math.min(after, open[0]);
        numbers = [];
      }
      const pages = await this.pages(`${this.url}?after=${after}&numbers=${numbers.join(',')}`);
      pages.forEach((page) => this.merge(page));
    }
    if (this.values) {
      for (let i = 0; i < this.number.length; i++) this.value[i] ??= this.values[i]?.[0] ?? null;
    }
    this.complete = completeRows(this);
  }

  // Chart columns from `first` on: the server answers a page at a time, and each page's
  // `next` is where the following one starts (null after the last).
  async pages(first) {
    const pages = [await getJSON(first)];
    while (pages[pages.length - 1].next != null) {
      pages.push(await getJSON(`${this.url}?after=${pages[pages.length - 1].next}`));
    }
    return pages;
  }

  setColumns({ number, state, value, values = null, feasible = null, params }) {
    this.number = number;
    this.state = state;
    this.value = value;
    this.values = values;
    this.feasible = feasible;
    this.params = params;
    this.index = new Map(number.map((n, i) => [n, i]));
  }

  merge(delta) {
    const known = this.number.length;
    for (const name of Object.keys(delta.params)) {
      if (!(name in this.params)) this.params[name] = new Array(known).fill(null);
    }
    for (const name of ['values', 'feasible']) {
      if (delta[name] && !this[name]) this[name] = new Array(known).fill(null);
    }
    const columns = Object.entries(this.params);
    let ordered = true;
    delta.number.forEach((number, j) => {
      let i = this.index.get(number);
      if (i === undefined) {
        i = this.number.length;
        if (i > 0 && number < this.number[i - 1]) ordered = false;
        this.number.push(number);
        this.state.push(null);
        this.value.push(null);
        this.values?.push(null);
        this.feasible?.push(null);
        for (const [, column] of columns) column.push(null);
        this.index.set(number, i);
      }
      this.state[i] = delta.state[j];
      this.value[i] = delta.value[j];
      if (this.values) this.values[i] = delta.values?.[j] ?? null;
      if (this.feasible) this.feasible[i] = delta.feasible?.[j] ?? null;
      for (const [name, column] of columns) column[i] = delta.params[name]?.[j] ?? null;
    });
    if (!ordered) {
      const order = this.number.map((_, i) => i).sort((a, b) => this.number[a] - this.number[b]);
      const pick = (column) => order.map((i) => column[i]);
      this.setColumns({
        number: pick(this.number),
        state: pick(this.state),
        value: pick(this.value),
        values: this.values && pick(this.values),
        feasible: this.feasible && pick(this.feasible),
        params: Object.fromEntries(columns.map(([name, column]) => [name, pick(column)])),
      });
    }
  }
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

/** The chart columns of the params `study` searched (its `searched_params`, the rule
 * the best design card lists them by): a tie's or mirror's copy of a searched spec, and
 * what its study file fixed, left out; the structure and catalogue choices kept (as
 * choices); a searched axis (`b.joint.axis`) as the angles the search chose
 * (`b.joint.axis_theta`, `b.joint.axis_phi`), not its derived vector. A view of
 * `series` (its other columns shared); all of them from a server that does not say. */
export function searchedColumns(series, study) {
  if (!Array.isArray(study.searched_params)) return series;
  const searched = new Set(study.searched_params);
  const kept = (name) => searched.has(name) || searched.has(name.replace(/_(theta|phi)$/, ''));
  const params = Object.fromEntries(Object.entries(series.params).filter(([name]) => kept(name)));
  return Object.assign(Object.create(series), { params });
}

/** Whether a column holds a categorical param's choices as text or booleans. */
export function isChoices(column) {
  return column.some((value) => typeof value === 'string' || typeof value === 'boolean');
}

/** Each complete trial's choice replaced by its choice's mean score: the choices have no
 * order of their own, so the correlation says how strongly the choice goes with the score. */
function meanScores(series, column) {
  const sums = new Map();
  for (const i of series.complete) {
    if (column[i] === null || column[i] === undefined) continue;
    const [sum, count] = sums.get(column[i]) ?? [0, 0];
    sums.set(column[i], [sum + series.value[i], count + 1]);
  }
  return column.map((value) => {
    const found = sums.get(value);
    return found ? found[0] / found[1] : null;
  });
}

/**
 * Spearman rank correlation of each varying param with the score over complete trials
 * (a categorical one's choices ranked by their mean score), strongest first: a cheap
 * guide to which params matter (not a causal importance).
 */
export function paramCorrelations(series) {
  const result = [];
  for (const [name, values] of Object.entries(series.params)) {
    const column = isChoices(values) ? meanScores(series, values) : values;
    const xs = [];
    const ys = [];
    for (const i of series.complete) {
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
