// A study's header (name, state, what it searches and how) and its progress bar with
// counts; the progress bar and counts text serve the studies list too.

import { ago, badge, element, esc, finder } from './html.js';
import { setCrumbs } from './shell.js';

export function countsText(study) {
  const of = study.max_trials ? ` of ${study.max_trials}` : '';
  return (
    `${study.n_complete} complete · ${study.n_running} running · ${study.n_queued} queued · ` +
    `${study.n_failed} failed${study.n_pruned ? ` · ${study.n_pruned} pruned` : ''}${of}`
  );
}

export function progressBar(study, extraClass = '') {
  const total = Math.max(study.max_trials ?? study.n_trials, 1);
  const segment = (count, state) =>
    count > 0
      ? `<span class="segment ${state}" style="width:${((100 * count) / total).toFixed(3)}%"
           title="${count} ${state}"></span>`
      : '';
  return `<div class="progress ${extraClass}" role="img" aria-label="${esc(countsText(study))}">
    ${segment(study.n_complete, 'complete')}${segment(study.n_pruned ?? 0, 'pruned')}
    ${segment(study.n_failed, 'failed')}
    ${segment(study.n_running, 'running')}${segment(study.n_queued, 'queued')}</div>`;
}

export class StudyHeader {
  constructor(studyId) {
    this.root = element(`<div>
      <section class="study-head">
        <h1><span data-name>Study ${studyId}</span> <span data-state></span></h1>
        <p class="meta" data-meta></p>
      </section>
      <section class="card">
        <div data-progress></div>
        <p class="counts" data-counts></p>
      </section>
    </div>`);
    this.$ = finder(this.root);
  }

  render(s) {
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
      (s.n_pruned ? `<span class="count pruned">${s.n_pruned} pruned</span>` : '') +
      `<span class="meta">${s.n_trials} asked${s.max_trials ? ` of ${s.max_trials}` : ''}</span>`;
  }
}
