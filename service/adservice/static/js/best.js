// The best-design card: the best trial's score, link, the params its study searched (the
// whole design a click away) and URDF, its robot in 3D where the simulator starts it (when
// it has a URDF) and the image its worker rendered (when it uploaded one). A study
// of several objectives has no one best: the card counts its Pareto front instead and
// lists the designs on it (the Pareto panel draws them).

import { artifactNames, getJSON } from './api.js';
import { formatNumber } from './charts.js';
import { element, esc, finder, paramsTable, scoreSpread, spawnUrl, urdfLink, urdfUrl } from './html.js';
import { objectiveNames } from './pareto.js';
import { RobotView } from './robot-view.js';

/** The best trial's params: by default those the study searched (its `searched_params`,
 * the server's rule), the whole design after "Show all"; with a line saying how many
 * the study file fixed or the searched ones derive, and the toggle between the two. */
function bestParams(study, params, showAll) {
  const entries = Object.entries(params ?? {});
  const searched = study.searched_params ? new Set(study.searched_params) : null;
  const chosen = searched ? entries.filter(([k]) => searched.has(k)) : entries;
  const hidden = entries.length - chosen.length;
  const shown = showAll ? entries : chosen;
  const table = `<div class="params-scroll" data-best-params>${paramsTable(Object.fromEntries(shown))}</div>`;
  if (!hidden) return table;
  const note = showAll
    ? `the whole design: ${entries.length} params, ${chosen.length} of them searched`
    : `the ${chosen.length} searched params; ${hidden} more are fixed by the study file or ` +
      'follow from these (ties, mirrors, catalogues)';
  const toggle = showAll ? 'Searched only' : `Show all ${entries.length}`;
  return `${table}<p class="meta" data-best-note>${note}
    <button type="button" class="link" data-best-all aria-pressed="${showAll}">${toggle}</button></p>`;
}
export class BestCard {
  constructor(page) {
    this.page = page;
    this.trial = null;
    this.artifacts = [];
    this.key = null;
    this.model = null;
    this.showAll = false;
    this.root = element(`<section class="card best" data-best-card>
      <h2 data-best-title>Best design</h2>
      <div class="best-body">
        <p class="placeholder" data-best-placeholder>No complete trial yet</p>
        <figure class="robot" data-best-figure hidden>
          <div data-best-model hidden></div>
          <img data-best-image alt="The best trial's rendered design" hidden>
        </figure>
        <div data-best></div>
      </div>
    </section>`);
    this.$ = finder(this.root);
    this.root.addEventListener('click', (event) => {
      if (!event.target.closest('[data-best-all]')) return;
      this.showAll = !this.showAll;
      this.key = null;
      this.render();
    });
  }

  /** Whether the best trial may still get its image (uploads do not touch the study). */
  get awaitsImage() {
    return this.trial !== null && !this.artifacts.includes('robot.png');
  }

  async load() {
    const id = this.page.study.best_trial_id;
    if (id === null || id === undefined) {
      this.trial = null;
      this.artifacts = [];
      return;
    }
    if (this.trial?.id !== id) {
      const [trial, names] = await Promise.all([
        getJSON(`/api/v1/trials/${id}`),
        artifactNames(this.page.studyId, [id]),
      ]);
      this.trial = trial;
      this.artifacts = names[id] ?? [];
    } else if (this.awaitsImage) {
      this.artifacts = (await artifactNames(this.page.studyId, [id]))[id] ?? [];
    }
  }

  render() {
    if (objectiveNames(this.page.study).length) {
      this.renderFront();
      return;
    }
    const { study } = this.page;
    const trial = this.trial;
    const key = trial ? `${trial.id}|${this.artifacts.join(',')}|${this.showAll}` : '';
    if (key === this.key) return;
    this.key = key;
    // A plain URL (the sign-in cookie authenticates it): the server serves an artifact
    // inline only when its bytes are a raster image, so the page never wraps one itself.
    const imageUrl =
      trial && this.artifacts.includes('robot.png') ? `/api/v1/trials/${trial.id}/artifacts/robot.png` : null;
    const modelUrl = trial && urdfUrl(study, trial, this.artifacts);
    const startUrl = trial && spawnUrl(study, trial);
    this.$('best-placeholder').hidden = trial !== null;
    this.$('best-figure').hidden = !imageUrl && !modelUrl;
    const image = this.$('best-image');
    image.hidden = !imageUrl;
    if (!imageUrl) image.removeAttribute('src');
    else if (image.getAttribute('src') !== imageUrl) image.src = imageUrl;
    this.showModel(modelUrl, startUrl);
    if (!trial) {
      this.$('best').innerHTML = '';
      return;
    }
    const urdf = urdfLink(study, trial, this.artifacts, 'Download URDF');
    this.$('best').innerHTML = `
      <p class="best-value">${formatNumber(trial.value)}${scoreSpread(trial)}</p>
      <p>trial <a href="#" data-open-trial="${trial.id}">#${trial.number}</a>
        ${trial.worker_id ? `· by ${esc(trial.worker_id)}` : ''} ${urdf ? `· ${urdf}` : ''}</p>
      ${bestParams(study, trial.params, this.showAll)}`;
  }

  /** Several objectives: how many designs are on the Pareto front, and the first of them
   * with their values (each opens its trial). */
  renderFront() {
    const { study, pareto } = this.page;
    const front = pareto.front;
    const key = `front|${front.map((t) => t.id).join(',')}`;
    if (key === this.key) return;
    this.key = key;
    const names = objectiveNames(study);
    this.$('best-title').textContent = 'Pareto front';
    this.$('best-placeholder').hidden = front.length > 0;
    this.$('best-placeholder').textContent = 'No complete feasible trial yet';
    this.$('best-figure').hidden = true;
    const shown = front.slice(0, 12);
    const rows = shown
      .map(
        (trial) => `<tr><th><a href="#" data-open-trial="${trial.id}">#${trial.number}</a></th>
          ${names.map((_, k) => `<td class="num">${formatNumber(trial.values?.[k])}</td>`).join('')}</tr>`,
      )
      .join('');
    const more = front.length > shown.length ? `<p class="meta">and ${front.length - shown.length} more</p>` : '';
    this.$('best').innerHTML = front.length
      ? `<p class="best-value" data-front-count>${front.length}</p>
        <p>design${front.length === 1 ? '' : 's'} on the Pareto front: none better in every objective</p>
        <div class="params-scroll"><table class="kv front"><tr><th>trial</th>
          ${names.map((name) => `<th>${esc(name)}</th>`).join('')}</tr>${rows}</table>${more}</div>`
      : '';
  }

  showModel(url, startUrl) {
    const holder = this.$('best-model');
    holder.hidden = !url;
    if (!url) return;
    if (!this.model) {
      this.model = new RobotView();
      holder.append(this.model.root);
    }
    this.model.show(url, startUrl);
  }

  imageLoaded() {
    const image = this.$('best-image');
    if (image.hidden || !image.src || image.complete) return Promise.resolve();
    return new Promise((resolve) => {
      image.addEventListener('load', resolve, { once: true });
      image.addEventListener('error', resolve, { once: true });
    });
  }

  dispose() {
    this.model?.dispose();
  }
}
