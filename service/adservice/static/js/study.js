// A study's page (#/studies/ID; #/studies/ID/trials/N with trial N's dialog open): its
// panels, kept current by polling. A poll re-fetches
// only what changed: the study itself every poll (one small read), and the chart columns,
// the table page, the best design, (several objectives) the Pareto front and (one design)
// the repeats' spread only when the study's counts or updated_at moved;
// chart columns come as a delta (new trials and the ones last seen open), so a
// 10,000-trial study stays cheap to follow.

import { getJSON } from './api.js';
import { BestCard } from './best.js';
import { CurvesPanel } from './curves.js';
import { EdfPanel } from './edf.js';
import { Filters } from './filters.js';
import { StudyHeader } from './header.js';
import { HistoryPanel } from './history.js';
import { element } from './html.js';
import { NoteBox } from './notes.js';
import { ParamsPanel } from './params.js';
import { ParetoPanel } from './pareto.js';
import { Series, paramCorrelations, searchedColumns } from './series.js';
import { showError } from './shell.js';
import { SpreadCard } from './spread.js';
import {
  closeTrialDialog,
  openTrialDialog,
  openTrialNumber,
  showMissingTrial,
} from './trial-dialog.js';
import { TrialsPanel } from './trials.js';
import { UnservedCard, WorkersPanel } from './workers.js';

/** Timings the browser tests read: ms since navigation for the first full render of a
 * study page, and for each live update the ms from poll start to the next frame. */
const metrics = (window.adMetrics = { firstRenderMs: null, renders: [], updates: [] });

function nextFrame() {
  return new Promise((resolve) => requestAnimationFrame(() => setTimeout(resolve, 0)));
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
    study.n_pruned,
    study.best_trial_id,
  ].join('|');
}

export class StudyPage {
  constructor(view, studyId) {
    this.studyId = studyId;
    this.alive = true;
    this.study = null;
    this.signature = null;
    this.series = new Series(studyId);
    /** The varying params by rank correlation with the score, and their names. */
    this.correlations = [];
    this.searched = new Set();
    /** The chart columns of the params the study searched (searchedColumns). */
    this.searchedSeries = null;
    this.filters = new Filters();
    this.filters.onChange(() => {
      this.params.draw();
      this.trials.table.offset = 0;
      this.trials.refresh();
    });
    this.polls = 0;
    this.header = new StudyHeader(studyId);
    this.spread = new SpreadCard(this);
    this.history = new HistoryPanel(this);
    this.best = new BestCard(this);
    this.pareto = new ParetoPanel(this);
    this.params = new ParamsPanel(this);
    this.curves = new CurvesPanel(this);
    this.workers = new WorkersPanel(this);
    this.unserved = new UnservedCard(this);
    this.trials = new TrialsPanel(this);
    this.edf = new EdfPanel(this);
    this.note = new NoteBox(this.api('/note'), null);
    const noteCard = element('<section class="card" data-study-note><h2>Note</h2></section>');
    noteCard.append(this.note.root);
    this.root = element('<div class="study"><div class="grid"></div></div>');
    this.root.querySelector('.grid').append(this.history.root, this.best.root);
    this.root.prepend(this.header.root, this.unserved.root, this.spread.root, noteCard);
    this.root.append(this.pareto.root, this.params.root, this.edf.root, this.curves.root, this.workers.root, this.trials.root);
    view.replaceChildren(this.root);
    this.root.addEventListener('click', (event) => {
      const opener = event.target.closest('a[data-open-trial]');
      if (opener && !opener.closest('[data-trials]')) {
        event.preventDefault();
        this.openTrial(Number(opener.dataset.openTrial));
      }
    });
    this.resizer = new ResizeObserver(() => {
      clearTimeout(this.resizeTimer);
      this.resizeTimer = setTimeout(() => this.series.loaded && this.drawCharts(), 120);
    });
    this.resizer.observe(this.root);
  }

  api(path) {
    return `/api/v1/studies/${this.studyId}${path}`;
  }

  async start() {
    const started = performance.now();
    this.study = await getJSON(this.api(''));
    this.signature = signatureOf(this.study);
    this.header.render(this.study);
    this.note.study = this.study;
    await Promise.all([
      this.note.load(),
      this.spread.load(),
      this.series.load(),
      this.trials.load(),
      this.best.load(),
      this.pareto.load(),
      this.workers.load(),
      this.unserved.load(),
      this.curves.load(),
    ]);
    if (!this.alive) return;
    this.drawCharts();
    this.spread.render();
    this.trials.render();
    this.best.render();
    this.workers.render();
    this.unserved.render();
    await this.best.imageLoaded();
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
    const scoresChanged = study.n_complete !== this.study.n_complete;
    this.study = study;
    this.note.study = study;
    this.signature = signatureOf(study);
    const work = [this.workers.load(), this.unserved.load()];
    if (this.polls % 5 === 0) work.push(this.note.load());
    const curvesDue = changed || this.curves.wanted(study);
    if (curvesDue) work.push(this.curves.load());
    if (changed) {
      work.push(this.series.load(), this.trials.load(), this.best.load(), this.pareto.load());
      work.push(this.spread.load());
    } else {
      // Uploads do not touch the study: look for images that may have arrived since.
      if (this.best.awaitsImage) work.push(this.best.load());
      if (this.polls % 5 === 0) work.push(this.trials.loadArtifacts(), this.pareto.loadPictures());
    }
    await Promise.all(work);
    if (!this.alive) return;
    const fetched = performance.now();
    this.header.render(study);
    if (changed) this.drawCharts({ scoresChanged });
    else if (curvesDue) this.curves.draw();
    this.spread.render();
    this.trials.render();
    this.best.render();
    this.workers.render();
    this.unserved.render();
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
    this.best.dispose();
  }

  /** The history always; the Pareto and params charts only when scores changed (new
   * complete trials), since they show complete trials only. */
  drawCharts({ scoresChanged = true } = {}) {
    this.history.draw();
    this.curves.draw();
    if (!scoresChanged) return;
    this.pareto.draw();
    this.edf.draw();
    this.searchedSeries = searchedColumns(this.series, this.study);
    this.correlations = paramCorrelations(this.searchedSeries);
    this.searched = new Set(this.correlations.map((c) => c.name));
    this.params.draw();
  }

  /** Trial `number`'s id, or null when the study has no such trial. */
  async trialIdOf(number) {
    const [trial] = await getJSON(this.api(`/trials?offset=${number}&limit=1&order_by=number`));
    return trial && trial.number === number ? trial.id : null;
  }

  async openTrialByNumber(number) {
    try {
      const trialId = await this.trialIdOf(number);
      if (trialId !== null) await this.openTrial(trialId);
    } catch (error) {
      showError(error);
    }
  }

  /** Open a trial's dialog (a click on it); the dialog gives it its address. */
  async openTrial(trialId) {
    try {
      await openTrialDialog(this.study, trialId);
    } catch (error) {
      showError(error);
    }
  }

  /** What the address says of the dialog (#/studies/ID/trials/N, or the study alone):
   * trial N's dialog open, or none. A number the study has no trial of: a dialog that
   * says so. */
  async showTrial(number) {
    if (number === null) {
      closeTrialDialog();
      return;
    }
    if (openTrialNumber() === number) return;
    try {
      const trialId = await this.trialIdOf(number);
      if (trialId === null) showMissingTrial(this.study, number);
      else await openTrialDialog(this.study, trialId);
    } catch (error) {
      showError(error);
    }
  }
}
