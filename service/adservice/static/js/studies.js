// The studies list (#/): every study with its state, progress, best score and activity,
// a checkbox each to compare some side by side (compare.js), and every worker the server
// has seen.

import { getJSON } from './api.js';
import { compareAddress } from './compare.js';
import { formatNumber } from './charts.js';
import { countsText, progressBar } from './header.js';
import { ago, badge, element, esc } from './html.js';
import { setCrumbs } from './shell.js';
import { ServerWorkersPanel } from './workers.js';

/** The best value and its direction; a study of several objectives has a Pareto front
 * instead (its page draws it): how many objectives. */
function best(s) {
  const count = (s.objective_names ?? []).length;
  if (count > 1) return `<span class="meta" title="see its Pareto front">${count} objectives</span>`;
  return `${formatNumber(s.best_value)} <span class="meta">${s.direction === 'maximize' ? '↑' : '↓'}</span>`;
}

export class StudiesPage {
  constructor(view) {
    this.root = element(`<div>
      <section class="card"><h2>Studies
        <button type="button" data-compare-picked disabled>Compare selected</button></h2>
        <div class="table-wrap" data-list>Loading…</div></section>
    </div>`);
    /** The studies ticked for comparison (kept across polls). */
    this.picked = new Set();
    const compare = this.root.querySelector('[data-compare-picked]');
    this.root.addEventListener('change', (event) => {
      const box = event.target.closest('input[data-pick]');
      if (!box) return;
      const id = Number(box.dataset.pick);
      if (box.checked) this.picked.add(id);
      else this.picked.delete(id);
      compare.disabled = this.picked.size < 2;
    });
    compare.addEventListener('click', () => {
      window.location.hash = compareAddress([...this.picked].sort((a, b) => a - b));
    });
    this.workers = new ServerWorkersPanel();
    this.root.append(this.workers.root);
    view.replaceChildren(this.root);
    this.alive = true;
    document.title = 'Studies · activedesign';
    setCrumbs('');
  }

  async start() {
    await this.poll();
  }

  async poll() {
    const [studies] = await Promise.all([getJSON('/api/v1/studies'), this.workers.poll()]);
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
          <td>${badge(s.state)}${s.proposal_failures > 0 ? ' <span class="tag failing">proposals failing</span>' : ''}</td>
          <td class="progress-cell">${progressBar(s, 'small')}<span class="meta">${esc(countsText(s))}</span></td>
          <td class="num">${best(s)}</td>
          <td title="${esc(s.updated_at)}">${ago(s.updated_at)}</td>
          <td><input type="checkbox" data-pick="${s.id}" aria-label="compare ${esc(s.name)}"
            ${this.picked.has(s.id) ? 'checked' : ''}></td>
        </tr>`,
      )
      .join('');
    target.innerHTML = `<table class="studies">
      <thead><tr><th>Study</th><th>State</th><th>Progress</th><th>Best</th><th>Last activity</th>
        <th title="tick two or more, then Compare selected">Compare</th></tr></thead>
      <tbody>${rows}</tbody></table>`;
  }

  stop() {
    this.alive = false;
  }
}
