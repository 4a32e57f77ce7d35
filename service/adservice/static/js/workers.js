// Workers: the study page's panel (who has leased this study's trials, what each holds
// now, the tasks and learners it serves, when it was last heard from, its jobs done and
// failed; "gone" for one the server has not heard from lately), the same table of every
// worker the server has seen on the studies list, and
// the study page's warning when no recent worker serves the study's task and learner
// (GET /studies/{id}/serving: the server's rule, the one `adclient status` prints).

import { getJSON } from './api.js';
import { ago, element, esc } from './html.js';

const STALE_SECONDS = 60;

/** What a worker named at its latest lease: the names, or "any" when it named none. */
function served(names) {
  return names === null || names === undefined
    ? '<span class="meta">any</span>'
    : esc(names.join(', '));
}

/** A worker the server has not heard from lately (its `state`, the server's rule): it
 * stopped, was killed or lost the server; a stopped adworker says nothing as it exits. */
const GONE =
  '<span class="meta" data-worker-state="gone" title="not heard from in the server\'s last 90 s: stopped, killed or cut off">gone</span>';

/** A table of workers; `holds(worker)` is the markup of its lease column (a gone worker's
 * is "gone", whatever it held). */
function workersTable(workers, holds) {
  const rows = workers
    .map((w) => {
      const age = (Date.now() - Date.parse(w.last_seen_at)) / 1000;
      const gone = w.state === 'gone';
      return `<tr class="${gone || age > STALE_SECONDS ? 'stale' : ''}" data-worker="${esc(w.worker_id)}">
        <td>${esc(w.worker_id)}</td><td>${gone ? GONE : holds(w)}</td>
        <td title="${esc(w.last_seen_at)}">${ago(w.last_seen_at)}</td>
        <td class="num">${w.jobs_done}</td><td class="num">${w.jobs_failed}</td>
        <td data-worker-tasks>${served(w.tasks)}</td>
        <td data-worker-learners>${served(w.learners)}</td></tr>`;
    })
    .join('');
  return `<table class="workers"><thead><tr><th>Worker</th><th>Lease</th>
    <th>Last contact</th><th>Jobs done</th><th>Failures</th><th>Tasks</th><th>Learners</th>
    </tr></thead><tbody>${rows}</tbody></table>`;
}

export class WorkersPanel {
  constructor(page) {
    this.page = page;
    this.workers = [];
    this.trialNumbers = new Map();
    this.root = element(`<section class="card">
      <h2>Workers</h2>
      <div class="table-wrap" data-workers></div>
    </section>`);
  }

  async load() {
    this.workers = await getJSON(this.page.api('/workers'));
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

  render() {
    const target = this.root.querySelector('[data-workers]');
    if (this.workers.length === 0) {
      target.innerHTML = '<p class="meta">No worker has leased a trial of this study.</p>';
      return;
    }
    target.innerHTML = workersTable(this.workers, (w) => {
      if (w.current_trial_id === null) return '<span class="meta">idle</span>';
      const number = this.trialNumbers.get(w.current_trial_id);
      return `<a href="#" data-open-trial="${w.current_trial_id}">trial #${number ?? '?'}</a>`;
    });
  }
}

/** Every worker the server has seen (GET /workers), for the studies list. */
export class ServerWorkersPanel {
  constructor() {
    this.root = element(`<section class="card">
      <h2>Workers <span class="meta">every worker this server has seen</span></h2>
      <div class="table-wrap" data-server-workers>Loading…</div>
    </section>`);
  }

  async poll() {
    const workers = await getJSON('/api/v1/workers');
    const target = this.root.querySelector('[data-server-workers]');
    if (workers.length === 0) {
      target.innerHTML =
        '<p class="meta">No worker has asked for work yet: start one with <code>adworker --server URL</code>.</p>';
      return;
    }
    target.innerHTML = workersTable(workers, (w) =>
      w.current_trial_id === null
        ? '<span class="meta">idle</span>'
        : `trial id ${w.current_trial_id}`,
    );
  }
}

/** A running managed study that no recent worker serves, idle for the server's
 * unserved_seconds: which task and learner it waits for and what to start. */
export class UnservedCard {
  constructor(page) {
    this.page = page;
    this.serving = null;
    this.root = element(`<section class="card unserved" data-unserved hidden>
      <h2>No worker serves this study</h2>
      <p data-unserved-text></p>
    </section>`);
  }

  async load() {
    const managed = this.page.study?.task && this.page.study.state === 'running';
    this.serving = managed ? await getJSON(this.page.api('/serving')) : null;
  }

  render() {
    const s = this.serving;
    this.root.hidden = !s?.unserved;
    if (!s?.unserved) return;
    this.root.querySelector('h2').innerHTML =
      `No worker serves task <code>${esc(s.task)}</code> with learner <code>${esc(s.learner)}</code>`;
    this.root.querySelector('[data-unserved-text]').textContent = s.text;
  }
}
