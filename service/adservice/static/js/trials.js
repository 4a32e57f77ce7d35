// The trials panel: a page of trials, sorted and filtered by the server, with each row's
// files; a row opens its trial. A study of several objectives has a column per objective
// instead of the score, and a star on the trials of its Pareto front; a trial that breaks
// the study's constraints is marked infeasible.

import { artifactNames, getJSON } from './api.js';
import { formatNumber } from './charts.js';
import { objectiveLabel, objectiveNames } from './pareto.js';
import { ago, badge, duration, element, esc, finder, formatParam, scoreSpread, urdfLink } from './html.js';
import { SCORE } from './filters.js';
import { showError } from './shell.js';
import { trialAddress } from './trial-dialog.js';

const HANDED_OVER = {
  enqueued: 'queued by its owner (POST /studies/{id}/trials), not proposed',
  added: 'an evaluation handed to the study (a warm start or an import), not run here',
};

/** A mark on trials the study's owner handed over rather than its proposer made. */
function handedOver(trial) {
  const source = trial.info?.source;
  if (!Object.hasOwn(HANDED_OVER, source)) return '';
  return ` <span class="meta" data-source="${esc(source)}" title="${esc(HANDED_OVER[source])}">${esc(source)}</span>`;
}

/** A mark on trials whose controller started from another trial's (task.transfer:
 * nearest), or that made a version of the study's shared controller (shared). */
function warmStarted(trial) {
  const source = trial.info?.transfer_from;
  if (Number.isInteger(source)) {
    return ` <span class="meta" data-transfer-from="${source}" title="its controller started from trial ${source}'s (task.transfer)">from trial ${source}</span>`;
  }
  const shared = trial.info?.shared;
  if (!Number.isInteger(shared?.version)) return '';
  const from = Number.isInteger(shared.from) ? `v${shared.from}` : 'initial';
  return ` <span class="meta" data-shared-version="${shared.version}" title="it started from the study's shared controller (${from}) and its update made version ${shared.version} (task.transfer: shared)">shared ${from} → v${shared.version}</span>`;
}

const COLUMNS = [
  { key: 'number', label: '#', sort: 'number' },
  { key: 'state', label: 'State', sort: 'state' },
  { key: 'value', label: 'Score', sort: 'value' },
  { key: 'worker', label: 'Worker', sort: 'worker_id' },
  { key: 'attempts', label: 'Attempts', sort: 'attempts' },
  { key: 'duration', label: 'Duration', sort: 'duration' },
  { key: 'finished', label: 'Finished', sort: 'finished_at' },
  { key: 'params', label: 'Params', sort: null },
  { key: 'files', label: 'Files', sort: null },
];

/** The table's columns: the score, or for several objectives one column per objective. */
function columnsFor(study) {
  const names = objectiveNames(study);
  if (names.length === 0) return COLUMNS;
  const objectives = names.map((_, k) => ({ key: `objective${k}`, label: objectiveLabel(study, k), sort: null }));
  return COLUMNS.flatMap((c) => (c.key === 'value' ? objectives : [c]));
}

/** A row's outcome cells: its score, or its value of each objective. */
function outcomeCells(study, trial) {
  const names = objectiveNames(study);
  if (names.length === 0) return `<td class="num">${formatNumber(trial.value)}${scoreSpread(trial)}</td>`;
  return names.map((_, k) => `<td class="num">${formatNumber(trial.values?.[k])}</td>`).join('');
}

/** The most trial numbers one table request lists (the server's MAX_LISTED): past it,
 * a filtered table is paged here, in order of number. */
const MAX_LISTED = 1000;

const INFEASIBLE = ' <span class="badge infeasible" title="breaks the study\'s constraints">infeasible</span>';

/** Params in the order a reader wants them: those searched (varying) first. */
function searchedFirst(params, searched) {
  const entries = Object.entries(params ?? {});
  return [
    ...entries.filter(([k]) => searched.has(k)),
    ...entries.filter(([k]) => !searched.has(k)),
  ];
}

export class TrialsPanel {
  constructor(page) {
    this.page = page;
    this.table = { offset: 0, limit: 25, orderBy: 'number', desc: true, state: '' };
    this.rows = [];
    this.total = 0;
    this.rowArtifacts = {};
    this.root = element(`<section class="card">
      <h2>Trials</h2>
      <div class="toolbar">
        <label>State <select data-filter>
          <option value="">all</option><option>complete</option><option>running</option>
          <option>queued</option><option>failed</option><option>pruned</option>
          <option>paused</option></select></label>
        <label>Rows <select data-page-size><option selected>25</option><option>50</option>
          <option>100</option><option>200</option></select></label>
        <label>Sort by param <select data-sort-param><option value="">—</option></select></label>
        <button data-sort-direction title="Reverse the param order" disabled>▲</button>
        <span class="spacer"></span>
        <button data-page="first" title="First page">«</button>
        <button data-page="prev" title="Previous page">‹</button>
        <span class="meta" data-page-info></span>
        <button data-page="next" title="Next page">›</button>
        <button data-page="last" title="Last page">»</button>
      </div>
      <form class="toolbar" data-range-form>
        <label>Filter <select data-range-name></select></label>
        <label>from <input data-range-low type="number" step="any" required></label>
        <label>to <input data-range-high type="number" step="any" required></label>
        <button>Filter</button>
        <span class="filters" data-filters></span>
      </form>
      <div class="table-wrap">
        <table class="trials" data-trials><thead><tr></tr></thead><tbody></tbody></table>
      </div>
    </section>`);
    this.$ = finder(this.root);
    this.columns = COLUMNS;
    this.headSignature = null;
    this.renderHeads(null);
    this.bindEvents();
  }

  /** The header row, rebuilt only when the study's columns change. */
  renderHeads(study) {
    const columns = columnsFor(study);
    const signature = columns.map((c) => c.label).join('\n');
    if (signature === this.headSignature) return;
    this.headSignature = signature;
    this.columns = columns;
    this.$('trials').tHead.rows[0].innerHTML = columns
      .map((c) => `<th${c.sort ? ` data-sort="${c.sort}" class="sortable"` : ''}>${esc(c.label)}</th>`)
      .join('');
  }

  bindEvents() {
    this.$('trials').addEventListener('click', (event) => {
      const head = event.target.closest('th[data-sort]');
      if (head) {
        const key = head.dataset.sort;
        this.table.desc = this.table.orderBy === key ? !this.table.desc : key !== 'number';
        this.table.orderBy = key;
        this.table.offset = 0;
        this.refresh();
        return;
      }
      if (event.target.closest('a[data-download]')) return;
      const opener = event.target.closest('[data-open-trial]');
      const row = event.target.closest('tr[data-trial-id]');
      if (opener || row) {
        event.preventDefault();
        this.page.openTrial(Number((opener ?? row).dataset.openTrial ?? row.dataset.trialId));
      }
    });
    this.$('filter').addEventListener('change', (event) => {
      this.table.state = event.target.value;
      this.table.offset = 0;
      this.refresh();
    });
    this.$('sort-param').addEventListener('change', (event) => {
      const name = event.target.value;
      this.table.orderBy = name ? `param:${name}` : 'number';
      this.table.desc = !name;
      this.table.offset = 0;
      this.refresh();
    });
    this.$('sort-direction').addEventListener('click', () => {
      this.table.desc = !this.table.desc;
      this.table.offset = 0;
      this.refresh();
    });
    this.$('range-form').addEventListener('submit', (event) => {
      event.preventDefault();
      const low = Number(this.$('range-low').value);
      const high = Number(this.$('range-high').value);
      this.page.filters.set(this.$('range-name').value, { low: Math.min(low, high), high: Math.max(low, high) });
    });
    this.$('filters').addEventListener('click', (event) => {
      const chip = event.target.closest('button[data-clear-filter]');
      if (chip) this.page.filters.clear(chip.dataset.clearFilter);
    });
    this.$('page-size').addEventListener('change', (event) => {
      this.table.limit = Number(event.target.value);
      this.table.offset = 0;
      this.refresh();
    });
    this.root.querySelector('.toolbar').addEventListener('click', (event) => {
      const button = event.target.closest('button[data-page]');
      if (!button) return;
      const { limit } = this.table;
      const lastOffset = Math.max(0, Math.floor((this.total - 1) / limit) * limit);
      const moves = {
        first: 0,
        prev: Math.max(0, this.table.offset - limit),
        next: Math.min(lastOffset, this.table.offset + limit),
        last: lastOffset,
      };
      this.table.offset = moves[button.dataset.page];
      this.refresh();
    });
  }

  async load() {
    const t = this.table;
    const query = new URLSearchParams({
      offset: t.offset,
      limit: t.limit,
      order_by: t.orderBy,
      desc: t.desc,
    });
    if (t.state) query.set('state', t.state);
    let passing = null;
    const { filters, series } = this.page;
    if (filters.active) {
      const numbers = filters.numbers(series);
      if (numbers.length === 0) {
        this.rows = [];
        this.total = 0;
        this.rowArtifacts = {};
        return;
      }
      if (numbers.length > MAX_LISTED) {
        // Too many to list: this page of them, in order of number, here.
        passing = numbers.length;
        const ordered = t.desc ? numbers.slice().reverse() : numbers;
        query.set('numbers', ordered.slice(t.offset, t.offset + t.limit).join(','));
        query.set('offset', 0);
      } else {
        query.set('numbers', numbers.join(','));
      }
    }
    const { body, total: answered } = await getJSON(this.page.api(`/trials?${query}`), { withTotal: true });
    const total = passing ?? answered;
    if (body.length === 0 && total > 0 && t.offset > 0) {
      t.offset = Math.floor((total - 1) / t.limit) * t.limit;
      return this.load();
    }
    this.rows = body;
    this.total = total;
    await this.loadArtifacts();
  }

  /** Uploads do not touch the study: the page asks now and then for new files. */
  async loadArtifacts() {
    this.rowArtifacts = await artifactNames(
      this.page.studyId,
      this.rows.map((row) => row.id),
    );
  }

  async refresh() {
    try {
      await this.load();
      if (this.page.alive) this.render();
    } catch (error) {
      showError(error);
    }
  }

  /** The params one can sort the table by (searched ones first), and the current one. */
  renderSortParam(searched) {
    const select = this.$('sort-param');
    const names = Object.keys(this.page.series.params);
    const ordered = [...names.filter((n) => searched.has(n)), ...names.filter((n) => !searched.has(n))];
    this.renderFilters(ordered);
    const current = this.table.orderBy.startsWith('param:') ? this.table.orderBy.slice(6) : '';
    const signature = ordered.join('\n');
    if (select.dataset.names !== signature) {
      select.dataset.names = signature;
      select.innerHTML = ['<option value="">—</option>', ...ordered.map((n) => `<option>${esc(n)}</option>`)].join('');
    }
    select.value = current;
    const direction = this.$('sort-direction');
    direction.disabled = !current;
    direction.textContent = current && this.table.desc ? '▼' : '▲';
  }

  /** The filter bar: the params one can filter by (numeric ones, searched first, and the
   * score) and a chip per active filter (a click clears it). */
  renderFilters(ordered) {
    const { series, filters } = this.page;
    const numeric = ordered.filter((name) => series.params[name].some((v) => typeof v === 'number'));
    const select = this.$('range-name');
    const signature = numeric.join('\n');
    if (select.dataset.names !== signature) {
      const current = select.value;
      select.dataset.names = signature;
      select.innerHTML = [`<option value="${esc(SCORE)}">score</option>`, ...numeric.map((n) => `<option>${esc(n)}</option>`)].join('');
      if (current) select.value = current;
    }
    this.$('filters').innerHTML = filters
      .describe()
      .map((f) => `<button type="button" class="chip" data-clear-filter="${esc(f.name)}" title="clear this filter">${esc(f.text)} ×</button>`)
      .join('');
  }

  render() {
    const { study, searched, pareto } = this.page;
    const { offset, limit, orderBy, desc } = this.table;
    this.renderHeads(study);
    const several = objectiveNames(study).length > 0;
    const body = this.rows
      .map((trial) => {
        const artifacts = this.rowArtifacts[trial.id] ?? [];
        const files = [];
        if (artifacts.includes('robot.png')) {
          files.push(`<a href="#" data-open-trial="${trial.id}" data-image>image</a>`);
        }
        const urdf = urdfLink(study, trial, artifacts);
        if (urdf) files.push(urdf);
        const others = artifacts.filter((n) => n !== 'robot.png' && n !== 'robot.urdf').length;
        if (others) files.push(`<span class="meta">+${others}</span>`);
        const params = searchedFirst(trial.params, searched)
          .map(([k, v]) => `${k}=${formatParam(v)}`)
          .join('  ');
        const best = several ? pareto.frontIds.has(trial.id) : trial.id === study.best_trial_id;
        const star = several ? 'on the Pareto front' : 'best';
        return `<tr data-trial-id="${trial.id}" class="${best ? 'is-best' : ''}">
          <td class="num"><a href="${trialAddress(study.id, trial.number)}" data-open-trial="${trial.id}">${trial.number}</a>${best ? ` <span title="${star}">★</span>` : ''}</td>
          <td>${badge(trial.state)}${trial.feasible === false ? INFEASIBLE : ''}${handedOver(trial)}${warmStarted(trial)}</td>
          ${outcomeCells(study, trial)}
          <td>${esc(trial.worker_id ?? '—')}</td>
          <td class="num">${trial.attempts}</td>
          <td class="num">${duration(trial)}</td>
          <td title="${esc(trial.finished_at ?? '')}">${trial.finished_at ? ago(trial.finished_at) : '—'}</td>
          <td class="params" title="${esc(params)}">${esc(params)}</td>
          <td class="files">${files.join(' ')}</td>
        </tr>`;
      })
      .join('');
    const trials = this.$('trials');
    trials.tBodies[0].innerHTML = body || `<tr><td colspan="${this.columns.length}" class="meta">No trials</td></tr>`;
    this.renderSortParam(searched);
    for (const head of trials.querySelectorAll('th[data-sort]')) {
      const active = head.dataset.sort === orderBy;
      head.classList.toggle('sorted', active);
      head.setAttribute('aria-sort', active ? (desc ? 'descending' : 'ascending') : 'none');
      head.dataset.arrow = active ? (desc ? '▼' : '▲') : '';
    }
    const first = this.total ? offset + 1 : 0;
    const filtered = this.page.filters.active ? ' passing the filters' : '';
    this.$('page-info').textContent = `${first}–${offset + this.rows.length} of ${this.total}${filtered}`;
    trials.dataset.total = String(this.total);
    this.root.querySelector('[data-page="prev"]').disabled = offset === 0;
    this.root.querySelector('[data-page="first"]').disabled = offset === 0;
    this.root.querySelector('[data-page="next"]').disabled = offset + limit >= this.total;
    this.root.querySelector('[data-page="last"]').disabled = offset + limit >= this.total;
  }
}
