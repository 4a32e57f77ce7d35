// A study's header (name, state, what it searches and how, its user attributes, and stop
// and delete buttons for those who may) and its progress bar with counts; the progress bar
// and counts text serve the studies list too. A running study with no max_trials (an
// Optuna sampler's, an ask/tell script's) has no end to measure progress against: its bar
// is faded and its counts say "no trial limit", so all complete does not read as done.

import { deleteStudy, mayManage, stopStudy } from './api.js';
import { ago, attrText, badge, element, esc, finder } from './html.js';
import { setCrumbs } from './shell.js';

/** A running study with no max_trials: it ends only when stopped. */
const openEnded = (study) => !study.max_trials && study.state === 'running';

export function countsText(study) {
  const of = study.max_trials ? ` of ${study.max_trials}` : openEnded(study) ? ' · no trial limit' : '';
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
  const faded = openEnded(study)
    ? ` data-open-ended style="opacity:0.5" title="no trial limit (max_trials): the bar shows its trials' states, not how far it has come; it runs until stopped"`
    : '';
  return `<div class="progress ${extraClass}" role="img" aria-label="${esc(countsText(study))}"${faded}>
    ${segment(study.n_complete, 'complete')}${segment(study.n_pruned ?? 0, 'pruned')}
    ${segment(study.n_failed, 'failed')}
    ${segment(study.n_running, 'running')}${segment(study.n_queued, 'queued')}</div>`;
}

const verb = (direction) => (direction === 'maximize' ? 'maximise' : 'minimise');

/** What the study optimises: its direction, or each objective's for several, and the
 * constraints a trial must meet to count. */
function aims(s) {
  const names = s.objective_names ?? [];
  const goal =
    names.length > 1
      ? names.map((name, k) => `${verb(s.directions[k])} ${esc(name)}`).join(', ')
      : verb(s.direction);
  const constraints = (s.constraints ?? []).map((c) => `${esc(c.metric)} ${esc(c.op)} ${c.bound}`);
  return constraints.length ? `${goal} · subject to ${constraints.join(', ')}` : goal;
}

/** A confirmation dialog of an action (data-NAME-dialog: its question, an error, Cancel and
 * the action's button). */
function confirmation(name, label) {
  return `<dialog class="confirm" data-${name}-dialog>
        <form method="dialog">
          <p data-${name}-question></p>
          <p class="error" data-${name}-error hidden></p>
          <div class="actions">
            <button value="cancel" data-${name}-cancel>Cancel</button>
            <button value="${name}" class="danger" data-${name}-confirm>${label}</button>
          </div>
        </form>
      </dialog>`;
}

export class StudyHeader {
  constructor(studyId) {
    this.root = element(`<div>
      <section class="study-head">
        <h1><span data-name>Study ${studyId}</span> <span data-state></span>
          <button type="button" class="stop" data-stop hidden>Stop study</button>
          <button type="button" class="danger" data-delete hidden>Delete study</button></h1>
        <p class="meta" data-meta></p>
        <p class="meta" data-attrs hidden></p>
        <p class="error" data-proposal-error hidden></p>
        <p class="warning" data-fallback hidden></p>
      </section>
      ${confirmation('stop', 'Stop')}
      ${confirmation('delete', 'Delete')}
      <section class="card">
        <div data-progress></div>
        <p class="counts" data-counts></p>
      </section>
    </div>`);
    this.$ = finder(this.root);
    this.study = null;
    this.$('stop').addEventListener('click', () => this.askToStop());
    this.$('stop-confirm').addEventListener('click', (event) => {
      event.preventDefault();
      this.stop();
    });
    this.$('delete').addEventListener('click', () => this.askToDelete());
    this.$('delete-confirm').addEventListener('click', (event) => {
      event.preventDefault();
      this.delete();
    });
  }

  /** The confirmation: names the study (as text) and what stopping does to its trials. */
  askToStop() {
    const s = this.study;
    const queued = s.n_queued ? ` Its ${s.n_queued} queued trials are dropped as failed.` : '';
    const running = s.n_running ? ` Its ${s.n_running} running trials may still be told.` : '';
    this.$('stop-question').textContent =
      `Stop study “${s.name}” (#${s.id})? No new trials are proposed or leased.` +
      `${queued}${running} Its trials and their files stay.`;
    this.$('stop-error').hidden = true;
    this.$('stop-dialog').showModal();
  }

  /** Stop; a refusal (a token that may not, a study gone) is said in the dialog. The
   * header shows the stopped study at once; the page's next poll brings the rest. */
  async stop() {
    const button = this.$('stop-confirm');
    button.disabled = true;
    try {
      this.render(await stopStudy(this.study.id));
    } catch (error) {
      this.$('stop-error').textContent = String(error.detail ?? error.message);
      this.$('stop-error').hidden = false;
      return;
    } finally {
      button.disabled = false;
    }
    this.$('stop-dialog').close();
  }

  /** The confirmation: names the study (as text) and what goes with it. */
  askToDelete() {
    const s = this.study;
    this.force = false;
    this.$('delete-question').textContent =
      `Delete study “${s.name}” (#${s.id}) with its ${s.n_trials} trials, their reports ` +
      'and artifacts? This cannot be undone.';
    this.$('delete-error').hidden = true;
    this.$('delete-confirm').textContent = 'Delete';
    this.$('delete-dialog').showModal();
  }

  /** Delete; while workers hold leases the server refuses (409): say so, and offer to
   * cancel their leases. Gone either way: back to the studies list. */
  async delete() {
    const button = this.$('delete-confirm');
    button.disabled = true;
    try {
      await deleteStudy(this.study.id, { force: this.force });
    } catch (error) {
      if (error.status !== 404) {
        this.$('delete-error').textContent = String(error.detail ?? error.message);
        this.$('delete-error').hidden = false;
        if (error.status === 409) {
          this.force = true;
          button.textContent = 'Delete and cancel the leases';
        }
        return;
      }
    } finally {
      button.disabled = false;
    }
    this.$('delete-dialog').close();
    window.location.hash = '#/';
  }

  /** A study whose proposals fail says so, and why (the error is text, never markup). */
  renderProposalError(s) {
    const failing = s.proposal_failures > 0;
    this.$('proposal-error').hidden = !failing;
    this.$('proposal-error').textContent = failing
      ? `Proposals failing (${s.proposal_failures} in a row; workers skip this study until ` +
        `${new Date(s.proposal_retry_at).toLocaleString()}): ${s.proposal_error ?? ''}`
      : '';
  }

  /** A model that fell back to Sobol points (a budget, a failed fit) is never silent. */
  renderFallback(s) {
    const fell = Boolean(s.proposal_fallback_reason);
    this.$('fallback').hidden = !fell;
    this.$('fallback').textContent = fell
      ? `The latest ask fell back to Sobol points (${s.proposal_fallbacks} ` +
        `candidate${s.proposal_fallbacks === 1 ? '' : 's'} so far): ${s.proposal_fallback_reason}`
      : '';
  }

  render(s) {
    this.study = s;
    this.$('delete').hidden = !mayManage(s);
    this.$('stop').hidden = !mayManage(s) || s.state !== 'running';
    const attrs = Object.entries(s.user_attrs ?? {});
    this.$('attrs').hidden = attrs.length === 0;
    this.$('attrs').textContent = attrs.map(([k, v]) => `${k}: ${attrText(v)}`).join(' · ');
    this.renderProposalError(s);
    this.renderFallback(s);
    document.title = `${s.name} · activedesign`;
    setCrumbs(`<a href="#/studies/${s.id}">${esc(s.name)}</a>`);
    this.$('name').textContent = s.name;
    this.$('state').innerHTML = badge(s.state);
    const task = s.task ? ` · task ${esc(s.task.name)} (${esc(s.task.learner)})` : ' · ask/tell';
    const space = {
      box: `${s.space.params?.length} params`,
      template: `robot template, ${s.space.params?.length} params`,
    }[s.space.type] ?? 'robot design space';
    this.$('meta').innerHTML =
      `${aims(s)} · ${s.fixed ? 'one design, no proposer' : `proposer ${esc(s.proposer.name)}`}` +
      `${task} · ${space}${s.created_by ? ` · by ${esc(s.created_by)}` : ''}` +
      ` · updated <span title="${esc(s.updated_at)}">${ago(s.updated_at)}</span>`;
    this.$('progress').innerHTML = progressBar(s);
    this.$('counts').innerHTML =
      `<span class="count complete">${s.n_complete} complete</span>` +
      `<span class="count running">${s.n_running} running</span>` +
      `<span class="count queued">${s.n_queued} queued</span>` +
      `<span class="count failed">${s.n_failed} failed</span>` +
      (s.n_pruned ? `<span class="count pruned">${s.n_pruned} pruned</span>` : '') +
      `<span class="meta">${s.n_trials} asked` +
      `${s.max_trials ? ` of ${s.max_trials}` : openEnded(s) ? ', no trial limit' : ''}</span>`;
  }
}
