// One trial in a dialog: its score, timings, message, metrics, params and user attributes;
// its robot in 3D
// (when it has a URDF), its image, its learning curve, and its files.

import { getJSON } from './api.js';
import { drawCurve, formatNumber } from './charts.js';
import { attrsTable, badge, duration, esc, paramsTable, spawnUrl, urdfLink, urdfUrl, when } from './html.js';
import { objectiveNames } from './pareto.js';
import { RobotView } from './robot-view.js';

const dialog = document.querySelector('[data-trial-dialog]');
let model = null; // the open trial's 3D view: one GPU context at a time

dialog.addEventListener('close', () => {
  model?.dispose();
  model = null;
});

/** The trial's score, or its value of each objective, and whether it meets the study's
 * constraints (when the study has some and the trial an outcome). */
function outcome(study, trial) {
  const names = objectiveNames(study);
  const values = names.length
    ? `<table class="kv" data-trial-values>${names
        .map((name, k) => `<tr><th>${esc(name)}</th><td>${formatNumber(trial.values?.[k])}</td></tr>`)
        .join('')}</table>`
    : `<p class="best-value">${formatNumber(trial.value)}</p>`;
  if (trial.feasible === null || trial.feasible === undefined) return values;
  const verdict = trial.feasible ? 'meets the constraints' : 'infeasible: breaks a constraint';
  return `${values}<p class="meta" data-trial-feasible="${trial.feasible}">${verdict}</p>`;
}

export async function openTrialDialog(study, trialId) {
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
  const modelUrl = urdfUrl(study, trial, names);
  model?.dispose();
  model = null;
  dialog.innerHTML = `<article class="trial">
    <header><h2>Trial #${trial.number} ${badge(trial.state)}</h2>
      <button class="close" data-close aria-label="Close">×</button></header>
    <div class="trial-body">
      <div>
        ${outcome(study, trial)}
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
        <div data-trial-attrs></div>
      </div>
      <div>
        ${modelUrl ? '<h3>Robot</h3><div data-trial-model></div>' : ''}
        ${names.includes('robot.png') ? '<img data-trial-image alt="The trial\'s rendered design">' : ''}
        ${names.includes('curve.json') ? '<h3>Learning curve</h3><canvas class="chart small" data-curve></canvas>' : ''}
        <h3>Files</h3>
        <ul class="files">${urdf ? `<li>${urdf}</li>` : ''}${files || '<li class="meta">No artifacts</li>'}</ul>
      </div>
    </div></article>`;
  if (Object.keys(trial.user_attrs ?? {}).length) {
    const heading = document.createElement('h3');
    heading.textContent = 'User attributes';
    dialog.querySelector('[data-trial-attrs]').append(heading, attrsTable(trial.user_attrs));
  }
  dialog.querySelector('[data-close]').addEventListener('click', () => dialog.close());
  if (!dialog.open) dialog.showModal();
  if (modelUrl) {
    model = new RobotView();
    dialog.querySelector('[data-trial-model]').append(model.root);
    model.show(modelUrl, spawnUrl(study, trial));
  }
  const image = dialog.querySelector('[data-trial-image]');
  if (image) image.src = `/api/v1/trials/${trial.id}/artifacts/robot.png`;
  const curve = dialog.querySelector('[data-curve]');
  if (curve) drawCurve(curve, await getJSON(`/api/v1/trials/${trial.id}/artifacts/curve.json`));
}
