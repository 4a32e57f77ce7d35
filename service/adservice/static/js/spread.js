// The repeats card of a study of one design (its space searches nothing, `fixed`): each
// objective's spread over the complete repeats, as GET /studies/{id}/spread gives it.
// Hidden for every other study.

import { getJSON } from './api.js';
import { formatNumber } from './charts.js';
import { element, esc } from './html.js';

const NUMBERS = ['mean', 'std', 'min', 'median', 'max'];

export class SpreadCard {
  constructor(page) {
    this.page = page;
    this.spread = null;
    this.root = element(`<section class="card spread" data-spread-card hidden>
      <h2>Repeats of one design</h2>
      <p class="meta">The space searches nothing: every trial evaluates its one design on a
        seed of its own (the study's seed plus the trial's number).</p>
      <div class="table-wrap" data-spread></div>
    </section>`);
  }

  async load() {
    this.spread = this.page.study.fixed ? await getJSON(this.page.api('/spread')) : null;
  }

  render() {
    this.root.hidden = this.spread === null;
    if (this.spread === null) return;
    const cell = (value) => `<td class="num">${value === null ? '—' : esc(formatNumber(value))}</td>`;
    const rows = this.spread.objectives
      .map(
        (o) =>
          `<tr><th scope="row">${esc(o.name)}</th><td class="num">${o.n}</td>` +
          `${NUMBERS.map((name) => cell(o[name])).join('')}</tr>`,
      )
      .join('');
    this.root.querySelector('[data-spread]').innerHTML =
      `<table class="spread"><thead><tr><th>Objective</th><th class="num">Repeats</th>` +
      `${NUMBERS.map((name) => `<th class="num">${name}</th>`).join('')}</tr></thead>` +
      `<tbody>${rows}</tbody></table>`;
  }
}
