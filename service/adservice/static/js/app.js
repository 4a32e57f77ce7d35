// The dashboard: a studies list (#/) and a study page (#/studies/ID), kept current by
// polling. A study page re-fetches only what changed: the study itself every poll (one
// small read), and the chart columns, the table page and the best design only when the
// study's counts or updated_at moved; chart columns come as a delta (new trials and the
// ones last seen open), so a 10,000-trial study stays cheap to follow.

import { HttpError, currentSession, getJSON, signIn, signOut } from './api.js';
import {
  drawCurve,
  drawHistory,
  drawParallel,
  drawSlices,
  formatNumber,
  nearestPoint,
  paramCorrelations,
} from './charts.js';

const POLL_MS = 2000;
const PARALLEL_AXES = 8;
const SLICE_PLOTS = 12;
const STALE_SECONDS = 60;

/** Timings the browser tests read: ms since navigation for the first full render of a
 * study page, and for each live update the ms from poll start to the next frame. */
const metrics = (window.adMetrics = { firstRenderMs: null, renders: [], updates: [] });

// --- small helpers ---------------------------------------------------------------------

function esc(text) {
  return String(text ?? '').replace(
    /[&<>"']/g,
    (c) => ({ '&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;', "'": '&#39;' })[c],
  );
}

function ago(iso) {
  if (!iso) return '—';
  const seconds = (Date.now() - Date.parse(iso)) / 1000;
  if (seconds < 2) return 'just now';
  if (seconds < 60) return `${Math.round(seconds)} s ago`;
  if (seconds < 3600) return `${Math.round(seconds / 60)} min ago`;
  if (seconds < 86400) return `${Math.round(seconds / 3600)} h ago`;
  return new Date(iso).toLocaleString();
}

function when(iso) {
  return iso ? `<span title="${esc(iso)}">${new Date(iso).toLocaleString()}</span>` : '—';
}

function seconds(value) {
  if (value < 1) return `${Math.round(value * 1000)} ms`;
  if (value < 60) return `${value.toFixed(1)} s`;
  if (value < 3600) return `${Math.floor(value / 60)} min ${Math.round(value % 60)} s`;
  return `${Math.floor(value / 3600)} h ${Math.round((value % 3600) / 60)} min`;
}

function duration(trial) {
  if (!trial.started_at) return '—';
  const end = trial.finished_at ? Date.parse(trial.finished_at) : Date.now();
  const text = seconds(Math.max(0, end - Date.parse(trial.started_at)) / 1000);
  return trial.finished_at ? text : `${text}…`;
}

function nextFrame() {
  return new Promise((resolve) => requestAnimationFrame(() => setTimeout(resolve, 0)));
}

const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

function element(html) {
  const template = document.createElement('template');
  template.innerHTML = html.trim();
  return template.content.firstElementChild;
}

function formatParam(value) {
  if (typeof value === 'number') return formatNumber(value);
  if (Array.isArray(value)) return `[${value.map(formatParam).join(', ')}]`;
  return String(value);
}

function progressBar(study, extraClass = '') {
  const total = Math.max(study.max_trials ?? study.n_trials, 1);
  const segment = (count, state) =>
    count > 0
      ? `<span class="segment ${state}" style="width:${((100 * count) / total).toFixed(3)}%"
           title="${count} ${state}"></span>`
      : '';
  return `<div class="progress ${extraClass}" role="img" aria-label="${esc(countsText(study))}">
    ${segment(study.n_complete, 'complete')}${segment(study.n_failed, 'failed')}
    ${segment(study.n_running, 'running')}${segment(study.n_queued, 'queued')}</div>`;
}

function countsText(study) {
  const of = study.max_trials ? ` of ${study.max_trials}` : '';
  return (
    `${study.n_complete} complete · ${study.n_running} running · ${study.n_queued} queued · ` +
    `${study.n_failed} failed${of}`
  );
}

function badge(state) {
  return `<span class="badge ${esc(state)}">${esc(state)}</span>`;
}

function urdfUrl(study, trial, artifacts) {
  if (study.space?.type && study.space.type !== 'box') return `/api/v1/trials/${trial.id}/urdf`;
  if (artifacts.includes('robot.urdf')) return `/api/v1/trials/${trial.id}/artifacts/robot.urdf`;
  return null;
}

function urdfLink(study, trial, artifacts, label = 'URDF') {
  const url = urdfUrl(study, trial, artifacts);
  if (!url) return '';
  const file = `trial-${trial.number}.urdf`;
  return `<a href="${url}" download="${file}" data-download="${file}">${label}</a>`;
}

function paramsTable(params) {
  const rows = Object.entries(params ?? {})
    .map(([k, v]) => `<tr><th>${esc(k)}</th><td>${esc(formatParam(v))}</td></tr>`)
    .join('');
  return `<table class="kv">${rows}</table>`;
}

/** Params in the order a reader wants them: those searched (varying) first. */
function searchedFirst(params, searched) {
  const entries = Object.entries(params ?? {});
  return [
    ...entries.filter(([k]) => searched.has(k)),
    ...entries.filter(([k]) => !searched.has(k)),
  ];
}

/** The params that vary across the study (and text ones like the structure) first; the
 * fixed ones folded away. */
function bestParams(params, searched) {
  const entries = Object.entries(params ?? {});
  const shown = entries.filter(([k, v]) => searched.has(k) || typeof v === 'string');
  const folded = entries.filter(([k, v]) => !(searched.has(k) || typeof v === 'string'));
  if (shown.length === 0) return `<div class="params-scroll">${paramsTable(params)}</div>`;
  const more = folded.length
    ? `<details><summary>${folded.length} more (fixed) params</summary>
        ${paramsTable(Object.fromEntries(folded))}</details>`
    : '';
  return `<div class="params-scroll">${paramsTable(Object.fromEntries(shown))}${more}</div>`;
}

// --- the studies list ------------------------------------------------------------------

class StudiesPage {
  constructor(view) {
    this.root = element(`<div>
      <section class="card"><h2>Studies</h2><div class="table-wrap" data-list>Loading…</div></section>
    </div>`);
    view.replaceChildren(this.root);
    this.alive = true;
    document.title = 'Studies · activedesign';
    setCrumbs('');
  }

  async start() {
    await this.poll();
  }

  async poll() {
    const studies = await getJSON('/api/v1/studies');
    if (!this.alive) return;
    const target = this.root.querySelector('[data-list]');
    if (studies.length === 0) {
      target.innerHTML =
        '<p class="meta">No studies yet. Create one with <code>adclient</code> or POST /api/v1/studies.</p>';
      return;
    }
    const rows = studies
      .slice()
      .sort((a, b) => b.id - a.id)
      .map(
        (s) => `<tr>
          <td><a href="#/studies/${s.id}">${esc(s.name)}</a> <span class="meta">#${s.id}</span>
            ${s.task ? `<span class="tag">${esc(s.task.name)}</span>` : ''}</td>
          <td>${badge(s.state)}</td>
          <td class="progress-cell">${progressBar(s, 'small')}<span class="meta">${esc(countsText(s))}</span></td>
          <td class="num">${formatNumber(s.best_value)} <span class="meta">${s.direction === 'maximize' ? '↑' : '↓'}</span></td>
          <td title="${esc(s.updated_at)}">${ago(s.updated_at)}</td>
        </tr>`,
      )
      .join('');
    target.innerHTML = `<table class="studies">
      <thead><tr><th>Study</th><th>State</th><th>Progress</th><th>Best</th><th>Last activity</th></tr></thead>
      <tbody>${rows}</tbody></table>`;
  }

  stop() {
    this.alive = false;
  }
}

// --- a study ---------------------------------------------------------------------------

const TABLE_COLUMNS = [
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

class StudyPage {
  constructor(view, studyId) {
    this.studyId = studyId;
    this.alive = true;
    this.signature = null;
    this.series = null;
    this.index = new Map();
    this.correlations = [];
    this.table = { offset: 0, limit: 25, orderBy: 'number', desc: true, state: '' };
    this.rows = [];
    this.total = 0;
    this.rowArtifacts = {};
    this.best = null;
    this.bestArtifacts = [];
    this.bestImage = { trialId: null, url: null };
    this.bestKey = null;
    this.workers = [];
    this.trialNumbers = new Map();
    this.tab = 'parallel';
    this.polls = 0;
    this.root = element(this.skeleton());
    view.replaceChildren(this.root);
    this.$ = (name) => this.root.querySelector(`[data-${name}]`);
    this.bindEvents();
  }

  skeleton() {
    const heads = TABLE_COLUMNS.map(
      (c) => `<th${c.sort ? ` data-sort="${c.sort}" class="sortable"` : ''}>${c.label}</th>`,
    ).join('');
    return `<div class="study">
      <section class="study-head">
        <h1><span data-name>Study ${this.studyId}</span> <span data-state></span></h1>
        <p class="meta" data-meta></p>
      </section>
      <section class="card">
        <div data-progress></div>
        <p class="counts" data-counts></p>
      </section>
      <div class="grid">
        <section class="card">
          <h2>Score by trial
            <span class="legend"><i class="dot"></i>score <i class="line"></i>best so far
            <i class="tick failed"></i>failed <i class="tick open"></i>queued/running</span></h2>
          <div class="chart-wrap">
            <canvas class="chart" data-history></canvas>
            <div class="tooltip" data-tooltip hidden></div>
          </div>
        </section>
        <section class="card best" data-best-card>
          <h2>Best design</h2>
          <div class="best-body">
            <figure class="robot">
              <img data-best-image alt="The best trial's rendered design" hidden>
              <div class="placeholder" data-best-placeholder>No design yet</div>
            </figure>
            <div data-best></div>
          </div>
        </section>
      </div>
      <section class="card">
        <h2>Params and score</h2>
        <nav class="tabs" data-tabs>
          <button data-tab="parallel" class="active">Parallel coordinates</button>
          <button data-tab="slices">Slices</button>
          <button data-tab="correlation">Rank correlation</button>
        </nav>
        <p class="meta" data-params-note></p>
        <canvas class="chart tall" data-parallel></canvas>
        <div class="slices" data-slices hidden></div>
        <div class="correlation" data-correlation hidden></div>
      </section>
      <section class="card">
        <h2>Workers</h2>
        <div class="table-wrap" data-workers></div>
      </section>
      <section class="card">
        <h2>Trials</h2>
        <div class="toolbar">
          <label>State <select data-filter>
            <option value="">all</option><option>complete</option><option>running</option>
            <option>queued</option><option>failed</option></select></label>
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
        <div class="table-wrap">
          <table class="trials" data-trials><thead><tr>${heads}</tr></thead><tbody></tbody></table>
        </div>
      </section>

    </div>`;
  }

  bindEvents() {
    const history = this.$('history');
    const tooltip = this.$('tooltip');
    history.addEventListener('mousemove', (event) => {
      const point = nearestPoint(history, event.offsetX, event.offsetY);
      history.style.cursor = point ? 'pointer' : 'default';
      if (!point) {
        tooltip.hidden = true;
        return;
      }
      tooltip.hidden = false;
      tooltip.textContent = `trial #${point.number}: ${formatNumber(point.value)}`;
      tooltip.style.left = `${event.offsetX + 12}px`;
      tooltip.style.top = `${event.offsetY - 8}px`;
    });
    history.addEventListener('mouseleave', () => {
      tooltip.hidden = true;
    });
    history.addEventListener('click', (event) => {
      const point = nearestPoint(history, event.offsetX, event.offsetY);
      if (point) this.openTrialByNumber(point.number);
    });
    this.$('tabs').addEventListener('click', (event) => {
      const button = event.target.closest('button[data-tab]');
      if (!button) return;
      this.tab = button.dataset.tab;
      for (const b of this.$('tabs').querySelectorAll('button')) {
        b.classList.toggle('active', b === button);
      }
      this.drawParams();
    });
    this.$('trials').addEventListener('click', (event) => {
      const head = event.target.closest('th[data-sort]');
      if (head) {
        const key = head.dataset.sort;
        this.table.desc = this.table.orderBy === key ? !this.table.desc : key !== 'number';
        this.table.orderBy = key;
        this.table.offset = 0;
        this.refreshTable();
        return;
      }
      if (event.target.closest('a[data-download]')) return;
      const opener = event.target.closest('[data-open-trial]');
      const row = event.target.closest('tr[data-trial-id]');
      if (opener || row) {
        event.preventDefault();
        this.openTrial(Number((opener ?? row).dataset.openTrial ?? row.dataset.trialId));
      }
    });
    this.root.addEventListener('click', (event) => {
      const opener = event.target.closest('a[data-open-trial]');
      if (opener && !opener.closest('[data-trials]')) {
        event.preventDefault();
        this.openTrial(Number(opener.dataset.openTrial));
      }
    });
    this.$('filter').addEventListener('change', (event) => {
      this.table.state = event.target.value;
      this.table.offset = 0;
      this.refreshTable();
    });
    this.$('sort-param').addEventListener('change', (event) => {
      const name = event.target.value;
      this.table.orderBy = name ? `param:${name}` : 'number';
      this.table.desc = !name;
      this.table.offset = 0;
      this.refreshTable();
    });
    this.$('sort-direction').addEventListener('click', () => {
      this.table.desc = !this.table.desc;
      this.table.offset = 0;
      this.refreshTable();
    });
    this.$('page-size').addEventListener('change', (event) => {
      this.table.limit = Number(event.target.value);
      this.table.offset = 0;
      this.refreshTable();
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
      this.refreshTable();
    });
    this.resizer = new ResizeObserver(() => {
      clearTimeout(this.resizeTimer);
      this.resizeTimer = setTimeout(() => this.series && this.drawCharts(), 120);
    });
    this.resizer.observe(this.root);
  }

  api(path) {
    return `/api/v1/studies/${this.studyId}${path}`;
  }

  async start() {
    const started = performance.now();
    const study = await getJSON(this.api(''));
    this.study = study;
    this.signature = signatureOf(study);
    this.renderHead();
    await Promise.all([this.loadSeries(true), this.loadTable(), this.loadBest(), this.loadWorkers()]);
    if (!this.alive) return;
    this.drawCharts();
    this.renderTable();
    this.renderBest();
    this.renderWorkers();
    await this.bestImageLoaded();
    await nextFrame();
    metrics.renders.push(performance.now() - started);
    if (metrics.firstRenderMs === null) metrics.firstRenderMs = performance.now();
    this.root.dataset.ready = 'true';
  }

  async poll() {
    const started = performance.now();
    this.polls += 1;
    const study = await getJSON(this.api(''));
    if (!this.alive) return;
    const changed = signatureOf(study) !== this.signature;
    const scoresChanged = !this.study || study.n_complete !== this.study.n_complete;
    this.study = study;
    this.signature = signatureOf(study);
    const work = [this.loadWorkers()];
    if (changed) {
      work.push(this.loadSeries(false), this.loadTable(), this.loadBest());
    } else {
      // Uploads do not touch the study: look for images that may have arrived since.
      if (this.best && !this.bestArtifacts.includes('robot.png')) work.push(this.loadBest());
      if (this.polls % 5 === 0) work.push(this.loadRowArtifacts());
    }
    await Promise.all(work);
    if (!this.alive) return;
    const fetched = performance.now();
    this.renderHead();
    if (changed) this.drawCharts({ scoresChanged });
    this.renderTable();
    this.renderBest();
    this.renderWorkers();
    if (changed) {
      await nextFrame();
      const done = performance.now();
      metrics.updates.push({
        ms: done - started,
        fetchMs: fetched - started,
        renderMs: done - fetched,
        trials: this.series.number.length,
      });
    }
  }

  stop() {
    this.alive = false;
    this.resizer.disconnect();
  }

  // --- data ---

  async loadSeries(full) {
    const url = `/api/v1/dashboard/studies/${this.studyId}/series`;
    if (full || !this.series) {
      const [first, ...rest] = await this.seriesPages(url);
      this.series = first;
      this.reindex();
      rest.forEach((page) => this.merge(page));
      return;
    }
    const s = this.series;
    const open = [];
    for (let i = 0; i < s.number.length; i++) {
      if (s.state[i] === 'queued' || s.state[i] === 'running') open.push(s.number[i]);
    }
    let after = s.number.length ? s.number[s.number.length - 1] + 1 : 0;
    let numbers = open;
    if (open.length > 500) {
      after = Math.min(after, open[0]);
      numbers = [];
    }
    const pages = await this.seriesPages(`${url}?after=${after}&numbers=${numbers.join(',')}`);
    pages.forEach((page) => this.merge(page));
  }

  // Chart columns from `first` on: the server answers a page at a time, and each page's
  // `next` is where the following one starts (null after the last).
  async seriesPages(first) {
    const pages = [await getJSON(first)];
    const base = first.split('?')[0];
    while (pages[pages.length - 1].next != null) {
      pages.push(await getJSON(`${base}?after=${pages[pages.length - 1].next}`));
    }
    return pages;
  }

  reindex() {
    const s = this.series;
    this.index = new Map(s.number.map((number, i) => [number, i]));
  }

  merge(delta) {
    const s = this.series;
    const known = s.number.length;
    for (const name of Object.keys(delta.params)) {
      if (!(name in s.params)) s.params[name] = new Array(known).fill(null);
    }
    const columns = Object.entries(s.params);
    let ordered = true;
    delta.number.forEach((number, j) => {
      let i = this.index.get(number);
      if (i === undefined) {
        i = s.number.length;
        if (i > 0 && number < s.number[i - 1]) ordered = false;
        s.number.push(number);
        s.state.push(null);
        s.value.push(null);
        for (const [, column] of columns) column.push(null);
        this.index.set(number, i);
      }
      s.state[i] = delta.state[j];
      s.value[i] = delta.value[j];
      for (const [name, column] of columns) column[i] = delta.params[name]?.[j] ?? null;
    });
    if (!ordered) {
      const order = s.number.map((_, i) => i).sort((a, b) => s.number[a] - s.number[b]);
      const pick = (column) => order.map((i) => column[i]);
      this.series = {
        number: pick(s.number),
        state: pick(s.state),
        value: pick(s.value),
        params: Object.fromEntries(columns.map(([name, column]) => [name, pick(column)])),
      };
      this.reindex();
    }
  }

  async artifactNames(trialIds) {
    if (trialIds.length === 0) return {};
    return getJSON(
      `/api/v1/dashboard/studies/${this.studyId}/artifacts?trial_ids=${trialIds.join(',')}`,
    );
  }

  async loadTable() {
    const t = this.table;
    const query = new URLSearchParams({
      offset: t.offset,
      limit: t.limit,
      order_by: t.orderBy,
      desc: t.desc,
    });
    if (t.state) query.set('state', t.state);
    const { body, total } = await getJSON(this.api(`/trials?${query}`), { withTotal: true });
    if (body.length === 0 && total > 0 && t.offset > 0) {
      t.offset = Math.floor((total - 1) / t.limit) * t.limit;
      return this.loadTable();
    }
    this.rows = body;
    this.total = total;
    await this.loadRowArtifacts();
  }

  async loadRowArtifacts() {
    this.rowArtifacts = await this.artifactNames(this.rows.map((row) => row.id));
  }

  async refreshTable() {
    try {
      await this.loadTable();
      if (this.alive) this.renderTable();
    } catch (error) {
      showError(error);
    }
  }

  async loadBest() {
    const id = this.study.best_trial_id;
    if (id === null || id === undefined) {
      this.best = null;
      this.bestArtifacts = [];
      return;
    }
    if (!this.best || this.best.id !== id) {
      const [trial, names] = await Promise.all([getJSON(`/api/v1/trials/${id}`), this.artifactNames([id])]);
      this.best = trial;
      this.bestArtifacts = names[id] ?? [];
    } else if (!this.bestArtifacts.includes('robot.png')) {
      this.bestArtifacts = (await this.artifactNames([id]))[id] ?? [];
    }
    if (this.bestArtifacts.includes('robot.png') && this.bestImage.trialId !== id) {
      // A plain URL (the sign-in cookie authenticates it): the server serves an artifact
      // inline only when its bytes are a raster image, so the page never wraps one itself.
      this.bestImage = { trialId: id, url: `/api/v1/trials/${id}/artifacts/robot.png` };
    }
  }

  async loadWorkers() {
    this.workers = await getJSON(this.api('/workers'));
    const unknown = this.workers
      .map((w) => w.current_trial_id)
      .filter((id) => id !== null && !this.trialNumbers.has(id));
    await Promise.all(
      unknown.map(async (id) => {
        const trial = await getJSON(`/api/v1/trials/${id}`);
        this.trialNumbers.set(id, trial.number);
      }),
    );
  }

  // --- rendering ---

  renderHead() {
    const s = this.study;
    document.title = `${s.name} · activedesign`;
    setCrumbs(`<a href="#/studies/${s.id}">${esc(s.name)}</a>`);
    this.$('name').textContent = s.name;
    this.$('state').innerHTML = badge(s.state);
    const task = s.task ? ` · task ${esc(s.task.name)} (${esc(s.task.learner)})` : ' · ask/tell';
    const space = s.space.type === 'box' ? `${s.space.params.length} params` : 'robot design space';
    this.$('meta').innerHTML =
      `${s.direction === 'maximize' ? 'maximise' : 'minimise'} · proposer ${esc(s.proposer.name)}` +
      `${task} · ${space}${s.created_by ? ` · by ${esc(s.created_by)}` : ''}` +
      ` · updated <span title="${esc(s.updated_at)}">${ago(s.updated_at)}</span>`;
    this.$('progress').innerHTML = progressBar(s);
    this.$('counts').innerHTML =
      `<span class="count complete">${s.n_complete} complete</span>` +
      `<span class="count running">${s.n_running} running</span>` +
      `<span class="count queued">${s.n_queued} queued</span>` +
      `<span class="count failed">${s.n_failed} failed</span>` +
      `<span class="meta">${s.n_trials} asked${s.max_trials ? ` of ${s.max_trials}` : ''}</span>`;
  }

  /** The history always; the params charts only when scores changed (new complete
   * trials), since they show complete trials only. */
  drawCharts({ scoresChanged = true } = {}) {
    drawHistory(this.$('history'), this.series, this.study.direction);
    if (!scoresChanged) return;
    this.correlations = paramCorrelations(this.series);
    this.drawParams();
  }

  drawParams() {
    const parallel = this.$('parallel');
    const slices = this.$('slices');
    const correlation = this.$('correlation');
    parallel.hidden = this.tab !== 'parallel';
    slices.hidden = this.tab !== 'slices';
    correlation.hidden = this.tab !== 'correlation';
    const names = this.correlations.map((c) => c.name);
    const shown = this.tab === 'slices' ? SLICE_PLOTS : PARALLEL_AXES;
    const notes = [];
    if (names.length > shown && this.tab !== 'correlation') {
      notes.push(`The ${shown} of ${names.length} varying params most rank-correlated with the score.`);
    }
    if (this.tab === 'parallel') {
      const lines = drawParallel(parallel, this.series, names.slice(0, PARALLEL_AXES), this.study.direction);
      if (lines.drawn < lines.total) {
        notes.push(
          `Lines: the best ${lines.best.toLocaleString()} of ${lines.total.toLocaleString()} ` +
            `complete trials and an even sample of the rest (${lines.drawn.toLocaleString()} in all).`,
        );
      }
    } else if (this.tab === 'slices') {
      drawSlices(slices, this.series, names.slice(0, SLICE_PLOTS));
      notes.push('Colour: trial number, yellow early to purple late.');
    }
    this.$('params-note').textContent = notes.join(' ');
    if (this.tab === 'correlation') {
      correlation.innerHTML = this.correlations.length
        ? this.correlations
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

  /** The params one can sort the table by (searched ones first), and the current one. */
  renderSortParam(searched) {
    const select = this.$('sort-param');
    const names = Object.keys(this.series?.params ?? {});
    const ordered = [...names.filter((n) => searched.has(n)), ...names.filter((n) => !searched.has(n))];
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

  renderTable() {
    const { offset, limit, orderBy, desc } = this.table;
    const searched = new Set(this.correlations.map((c) => c.name));
    const body = this.rows
      .map((trial) => {
        const artifacts = this.rowArtifacts[trial.id] ?? [];
        const files = [];
        if (artifacts.includes('robot.png')) {
          files.push(`<a href="#" data-open-trial="${trial.id}" data-image>image</a>`);
        }
        const urdf = urdfLink(this.study, trial, artifacts);
        if (urdf) files.push(urdf);
        const others = artifacts.filter((n) => n !== 'robot.png' && n !== 'robot.urdf').length;
        if (others) files.push(`<span class="meta">+${others}</span>`);
        const params = searchedFirst(trial.params, searched)
          .map(([k, v]) => `${k}=${formatParam(v)}`)
          .join('  ');
        const best = trial.id === this.study.best_trial_id;
        return `<tr data-trial-id="${trial.id}" class="${best ? 'is-best' : ''}">
          <td class="num">${trial.number}${best ? ' <span title="best">★</span>' : ''}</td>
          <td>${badge(trial.state)}</td>
          <td class="num">${formatNumber(trial.value)}</td>
          <td>${esc(trial.worker_id ?? '—')}</td>
          <td class="num">${trial.attempts}</td>
          <td class="num">${duration(trial)}</td>
          <td title="${esc(trial.finished_at ?? '')}">${trial.finished_at ? ago(trial.finished_at) : '—'}</td>
          <td class="params" title="${esc(params)}">${esc(params)}</td>
          <td class="files">${files.join(' ')}</td>
        </tr>`;
      })
      .join('');
    const tbody = this.$('trials').tBodies[0];
    tbody.innerHTML = body || `<tr><td colspan="${TABLE_COLUMNS.length}" class="meta">No trials</td></tr>`;
    this.renderSortParam(searched);
    for (const head of this.$('trials').querySelectorAll('th[data-sort]')) {
      const active = head.dataset.sort === orderBy;
      head.classList.toggle('sorted', active);
      head.setAttribute('aria-sort', active ? (desc ? 'descending' : 'ascending') : 'none');
      head.dataset.arrow = active ? (desc ? '▼' : '▲') : '';
    }
    const first = this.total ? offset + 1 : 0;
    this.$('page-info').textContent = `${first}–${offset + this.rows.length} of ${this.total}`;
    this.$('trials').dataset.total = String(this.total);
    this.root.querySelector('[data-page="prev"]').disabled = offset === 0;
    this.root.querySelector('[data-page="first"]').disabled = offset === 0;
    this.root.querySelector('[data-page="next"]').disabled = offset + limit >= this.total;
    this.root.querySelector('[data-page="last"]').disabled = offset + limit >= this.total;
  }

  renderBest() {
    const trial = this.best;
    const image = this.$('best-image');
    const placeholder = this.$('best-placeholder');
    const searched = new Set(this.correlations.map((c) => c.name));
    const key = trial
      ? `${trial.id}|${this.bestArtifacts.join(',')}|${this.bestImage.url}|${searched.size}`
      : '';
    if (key === this.bestKey) return;
    this.bestKey = key;
    if (!trial) {
      image.hidden = true;
      placeholder.hidden = false;
      placeholder.textContent = 'No complete trial yet';
      this.$('best').innerHTML = '';
      return;
    }
    const hasImage = this.bestImage.trialId === trial.id && this.bestImage.url;
    if (hasImage) {
      if (image.src !== this.bestImage.url) image.src = this.bestImage.url;
      image.hidden = false;
      placeholder.hidden = true;
    } else {
      image.hidden = true;
      image.removeAttribute('src');
      placeholder.hidden = false;
      placeholder.textContent = 'No image uploaded (robot.png)';
    }
    const urdf = urdfLink(this.study, trial, this.bestArtifacts, 'Download URDF');
    this.$('best').innerHTML = `
      <p class="best-value">${formatNumber(trial.value)}</p>
      <p>trial <a href="#" data-open-trial="${trial.id}">#${trial.number}</a>
        ${trial.worker_id ? `· by ${esc(trial.worker_id)}` : ''} ${urdf ? `· ${urdf}` : ''}</p>
      ${bestParams(trial.params, searched)}`;
  }

  bestImageLoaded() {
    const image = this.$('best-image');
    if (image.hidden || !image.src || image.complete) return Promise.resolve();
    return new Promise((resolve) => {
      image.addEventListener('load', resolve, { once: true });
      image.addEventListener('error', resolve, { once: true });
    });
  }

  renderWorkers() {
    const target = this.$('workers');
    if (this.workers.length === 0) {
      target.innerHTML = '<p class="meta">No worker has leased a trial of this study.</p>';
      return;
    }
    const rows = this.workers
      .map((w) => {
        const age = (Date.now() - Date.parse(w.last_seen_at)) / 1000;
        const number = this.trialNumbers.get(w.current_trial_id);
        const holds =
          w.current_trial_id === null
            ? '<span class="meta">idle</span>'
            : `<a href="#" data-open-trial="${w.current_trial_id}">trial #${number ?? '?'}</a>`;
        return `<tr class="${age > STALE_SECONDS ? 'stale' : ''}">
          <td>${esc(w.worker_id)}</td><td>${holds}</td>
          <td title="${esc(w.last_seen_at)}">${ago(w.last_seen_at)}</td>
          <td class="num">${w.jobs_done}</td><td class="num">${w.jobs_failed}</td></tr>`;
      })
      .join('');
    target.innerHTML = `<table class="workers"><thead><tr><th>Worker</th><th>Lease</th>
      <th>Last heartbeat</th><th>Jobs done</th><th>Failures</th></tr></thead><tbody>${rows}</tbody></table>`;
  }

  // --- one trial ---

  async openTrialByNumber(number) {
    const query = this.api(`/trials?offset=${number}&limit=1&order_by=number`);
    const [trial] = await getJSON(query);
    if (trial && trial.number === number) this.openTrial(trial.id);
  }

  async openTrial(trialId) {
    try {
      await openTrialDialog(this.study, trialId);
    } catch (error) {
      showError(error);
    }
  }
}

function signatureOf(study) {
  return [
    study.updated_at,
    study.state,
    study.n_trials,
    study.n_queued,
    study.n_running,
    study.n_complete,
    study.n_failed,
    study.best_trial_id,
  ].join('|');
}

async function openTrialDialog(study, trialId) {
  const dialog = document.querySelector('[data-trial-dialog]');
  const [trial, artifacts] = await Promise.all([
    getJSON(`/api/v1/trials/${trialId}`),
    getJSON(`/api/v1/trials/${trialId}/artifacts`),
  ]);
  const names = artifacts.map((a) => a.name);
  const files = artifacts
    .map(
      (a) => `<li><a href="/api/v1/trials/${trial.id}/artifacts/${encodeURIComponent(a.name)}"
        download="${esc(a.name)}" data-download="trial-${trial.number}-${esc(a.name)}">${esc(a.name)}</a>
        <span class="meta">${a.size} bytes</span></li>`,
    )
    .join('');
  const metrics = Object.keys(trial.metrics ?? {}).length
    ? `<h3>Metrics</h3>${paramsTable(trial.metrics)}`
    : '';
  const urdf = urdfLink(study, trial, names, 'Download URDF');
  dialog.innerHTML = `<article class="trial">
    <header><h2>Trial #${trial.number} ${badge(trial.state)}</h2>
      <button class="close" data-close aria-label="Close">×</button></header>
    <div class="trial-body">
      <div>
        <p class="best-value">${formatNumber(trial.value)}</p>
        <table class="kv">
          <tr><th>worker</th><td>${esc(trial.worker_id ?? '—')}</td></tr>
          <tr><th>attempts</th><td>${trial.attempts}</td></tr>
          <tr><th>created</th><td>${when(trial.created_at)}</td></tr>
          <tr><th>started</th><td>${when(trial.started_at)}</td></tr>
          <tr><th>finished</th><td>${when(trial.finished_at)}</td></tr>
          <tr><th>duration</th><td>${duration(trial)}</td></tr>
        </table>
        ${trial.message ? `<h3>Message</h3><pre>${esc(trial.message)}</pre>` : ''}
        ${metrics}
        <h3>Params</h3>${paramsTable(trial.params)}
      </div>
      <div>
        ${names.includes('robot.png') ? '<img data-trial-image alt="The trial\'s rendered design">' : ''}
        ${names.includes('curve.json') ? '<h3>Learning curve</h3><canvas class="chart small" data-curve></canvas>' : ''}
        <h3>Files</h3>
        <ul class="files">${urdf ? `<li>${urdf}</li>` : ''}${files || '<li class="meta">No artifacts</li>'}</ul>
      </div>
    </div></article>`;
  dialog.querySelector('[data-close]').addEventListener('click', () => dialog.close());
  if (!dialog.open) dialog.showModal();
  const image = dialog.querySelector('[data-trial-image]');
  if (image) {
    image.src = `/api/v1/trials/${trial.id}/artifacts/robot.png`;
  }
  const curve = dialog.querySelector('[data-curve]');
  if (curve) drawCurve(curve, await getJSON(`/api/v1/trials/${trial.id}/artifacts/curve.json`));
}

// --- shell: routing, polling, errors ---------------------------------------------------

const view = document.querySelector('[data-view]');
let page = null;

function setCrumbs(html) {
  document.querySelector('[data-crumbs]').innerHTML = html ? `<span>›</span> ${html}` : '';
}

function setLive(ok, detail = '') {
  const live = document.querySelector('[data-live]');
  live.classList.toggle('ok', ok);
  live.classList.toggle('down', !ok);
  live.title = ok ? `live · last update ${new Date().toLocaleTimeString()}` : `not updating: ${detail}`;
}

function askToSignIn(text) {
  const auth = document.querySelector('[data-auth]');
  auth.hidden = false;
  auth.querySelector('[data-auth-text]').textContent = text;
  document.querySelector('[data-signed-in]').hidden = true;
}

function showSignedIn(session) {
  document.querySelector('[data-auth]').hidden = true;
  const who = document.querySelector('[data-signed-in]');
  who.hidden = !session.auth || !session.signed_in;
  who.querySelector('[data-who]').textContent = session.name
    ? `${session.name} (${session.role})`
    : session.role ?? '';
}

function showError(error) {
  console.error(error);
  if (error instanceof HttpError && error.status === 401) {
    askToSignIn('This server requires a token. Sign in with a reader token or higher:');
  }
  setLive(false, error.message);
}

async function route() {
  page?.stop();
  const match = window.location.hash.match(/^#\/studies\/(\d+)/);
  const current = match ? new StudyPage(view, Number(match[1])) : new StudiesPage(view);
  page = current;
  try {
    await current.start();
    current.ready = true;
    setLive(true);
  } catch (error) {
    if (error instanceof HttpError && error.status === 404) {
      current.gone = true;
      view.innerHTML = `<section class="card"><h2>Not found</h2><p>${esc(error.message)}</p>
        <p><a href="#/">All studies</a></p></section>`;
    }
    showError(error);
  }
}

async function pollForever() {
  for (;;) {
    await sleep(POLL_MS);
    const current = page;
    if (document.hidden || !current || current.gone) continue;
    try {
      if (current.ready) await current.poll();
      else await route(); // the first load failed (server down, no token): try again
      setLive(true);
    } catch (error) {
      showError(error);
    }
  }
}

document.querySelector('[data-auth] form').addEventListener('submit', async (event) => {
  event.preventDefault();
  const field = event.target.elements.token;
  try {
    showSignedIn(await signIn(field.value));
    field.value = '';
    route();
  } catch (error) {
    field.value = '';
    askToSignIn(`The server refused that token (${error.message}). Try another:`);
  }
});

document.querySelector('[data-sign-out]').addEventListener('click', async () => {
  await signOut();
  page?.stop();
  view.innerHTML = '';
  askToSignIn('Signed out. Sign in with a reader token or higher:');
});

async function start() {
  try {
    const session = await currentSession();
    if (session.auth && !session.signed_in) {
      askToSignIn('This server requires a token. Sign in with a reader token or higher:');
    } else {
      showSignedIn(session);
    }
  } catch (error) {
    showError(error);
  }
  window.addEventListener('hashchange', route);
  route();
  pollForever();
}

start();
