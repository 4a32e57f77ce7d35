// The page's trial filters: a range of a param's values, a set of a categorical param's
// choices, or a range of the score, each set by brushing a parallel-coordinates axis or
// from the trial table's toolbar. A trial passes when it passes every one (a trial
// without that param, or without a score under a score filter, does not). The table
// lists the passing trials and the params panel draws them (the others greyed).

import { formatNumber } from './charts.js';

/** The key of the score's filter (no param is named so: names have no spaces). */
export const SCORE = ' score';

export class Filters {
  constructor() {
    /** name -> {low, high} (numbers) or {choices: Set of texts} */
    this.ranges = new Map();
    this.listeners = [];
  }

  get active() {
    return this.ranges.size > 0;
  }

  onChange(listener) {
    this.listeners.push(listener);
  }

  changed() {
    for (const listener of this.listeners) listener();
  }

  set(name, range) {
    this.ranges.set(name, range);
    this.changed();
  }

  clear(name) {
    if (name === undefined) this.ranges.clear();
    else this.ranges.delete(name);
    this.changed();
  }

  /** Whether row `i` of `series` passes every filter. */
  passes(series, i) {
    for (const [name, range] of this.ranges) {
      const value = name === SCORE ? series.value[i] : series.params[name]?.[i];
      if (value === null || value === undefined) return false;
      if (range.choices) {
        if (!range.choices.has(String(value))) return false;
      } else if (!(value >= range.low && value <= range.high)) {
        return false;
      }
    }
    return true;
  }

  /** The trial numbers of `series` that pass, in order of number. */
  numbers(series) {
    const passing = [];
    for (let i = 0; i < series.number.length; i++) {
      if (this.passes(series, i)) passing.push(series.number[i]);
    }
    return passing;
  }

  /** Each filter as text: `x in [0.2, 0.5]`, `act in {relu, gelu}`. */
  describe() {
    return [...this.ranges].map(([name, range]) => {
      const label = name === SCORE ? 'score' : name;
      const what = range.choices
        ? `{${[...range.choices].join(', ')}}`
        : `[${formatNumber(range.low)}, ${formatNumber(range.high)}]`;
      return { name, text: `${label} in ${what}` };
    });
  }
}
