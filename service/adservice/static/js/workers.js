// The workers panel: who has leased this study's trials, what each holds now, when it
// was last heard from, and its jobs done and failed.

import { getJSON } from './api.js';
import { ago, element, esc } from './html.js';

const STALE_SECONDS = 60;

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
}
