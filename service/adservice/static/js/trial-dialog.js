// One trial in a dialog: its score, timings, message, metrics, params and user attributes;
// its robot in 3D
// (when it has a URDF; with its worker's replay.json, playing the evaluation episode), its
// image, its learning curve, and its files.

import { getJSON } from './api.js';
import { drawCurve, formatNumber } from './charts.js';
import {
  attrsTable,
  badge,
  duration,
  esc,
  paramsTable,
  scoreSpread,
  spawnUrl,
  urdfLink,
  urdfUrl,
  when,
} from './html.js';
import { NoteBox } from './notes.js';
import { objectiveNames } from './pareto.js';
import { RobotView } from './robot-view.js';

const dialog = document.querySelector('[data-trial-dialog]');

/** The learning curve's place (curve.json, adclient.schemas.Curve): training episodes as a
 * line, evaluation episodes as dots, and what their score is, in the task's words. */
const CURVE = `<h3>Learning curve
    <span class="legend"><i class="line curve"></i>training episodes
    <i class="dot front"></i>evaluation episodes</span></h3>
  <canvas class="chart small" data-curve></canvas>
  <p class="meta" data-curve-score hidden></p>`;
let model = null; // the open trial's 3D view: one GPU context at a time
let shown = null; // the open trial: {studyId, number}

/** A trial's own address: its study's page with its dialog open. */
export function trialAddress(studyId, number) {
  return `#/studies/${studyId}/trials/${number}`;
}

/** The number of the trial the dialog shows, or null when it is closed. */
export function openTrialNumber() {
  return dialog.open && shown ? shown.number : null;
}

/** Close the dialog without touching the address (it already names no trial). */
export function closeTrialDialog() {
  if (dialog.open) dialog.close();
}

/** Closed by the reader (×, Esc) while the address names this trial: back to the study's
 * address, as the entry before it if opening the dialog added this one, else in its
 * place (the trial's address was opened as it is). */
function leaveTrialAddress(closed) {
  if (!closed || window.location.hash !== trialAddress(closed.studyId, closed.number)) return;
  if (window.history.state?.trialOpened) window.history.back();
  else window.history.replaceState(null, '', `#/studies/${closed.studyId}`);
}

dialog.addEventListener('close', () => {
  model?.dispose();
  model = null;
  const closed = shown;
  shown = null;
  leaveTrialAddress(closed);
});

/** The trial's score, or its value of each objective, and whether it meets the study's
 * constraints (when the study has some and the trial an outcome). */
function outcome(study, trial) {
  const names = objectiveNames(study);
  const values = names.length
    ? `<table class="kv" data-trial-values>${names
        .map((name, k) => `<tr><th>${esc(name)}</th><td>${formatNumber(trial.values?.[k])}</td></tr>`)
        .join('')}</table>`
    : `<p class="best-value">${formatNumber(trial.value)}${scoreSpread(trial)}</p>`;
  if (trial.feasible === null || trial.feasible === undefined) return values;
  const verdict = trial.feasible ? 'meets the constraints' : 'infeasible: breaks a constraint';
  return `${values}<p class="meta" data-trial-feasible="${trial.feasible}">${verdict}</p>`;
}

/** The dialog of an address whose study has no such trial: says so; closing it leaves
 * the address as closing a trial's does. */
export function showMissingTrial(study, number) {
  model?.dispose();
  model = null;
  dialog.innerHTML = `<article class="trial" data-missing-trial>
    <header><h2>No trial #${number}</h2>
      <button class="close" data-close aria-label="Close">×</button></header>
    <p>Study “${esc(study.name)}” (#${study.id}) has no trial #${number}.</p></article>`;
  dialog.querySelector('[data-close]').addEventListener('click', () => dialog.close());
  shown = { studyId: study.id, number };
  if (!dialog.open) dialog.showModal();
}

/** Open trial `trialId` of `study` in the dialog and give it its address (a new history
 * entry, unless the address names it already); resolves to the trial. */
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
        <h3>Note</h3><div data-trial-note></div>
      </div>
      <div>
        ${modelUrl ? '<h3>Robot</h3><div data-trial-model></div>' : ''}
        ${names.includes('robot.png') ? '<img data-trial-image alt="The trial\'s rendered design">' : ''}
        ${names.includes('curve.json') ? CURVE : ''}
        <h3>Files</h3>
        <ul class="files">${urdf ? `<li>${urdf}</li>` : ''}${files || '<li class="meta">No artifacts</li>'}</ul>
      </div>
    </div></article>`;
  if (Object.keys(trial.user_attrs ?? {}).length) {
    const heading = document.createElement('h3');
    heading.textContent = 'User attributes';
    dialog.querySelector('[data-trial-attrs]').append(heading, attrsTable(trial.user_attrs));
  }
  const note = new NoteBox(`/api/v1/trials/${trial.id}/note`, study);
  dialog.querySelector('[data-trial-note]').append(note.root);
  dialog.querySelector('[data-close]').addEventListener('click', () => dialog.close());
  shown = { studyId: study.id, number: trial.number };
  if (!dialog.open) dialog.showModal();
  note.load().catch((error) => note.root.replaceChildren(`No note: ${error.message}`));
  const address = trialAddress(study.id, trial.number);
  if (window.location.hash !== address) window.history.pushState({ trialOpened: true }, '', address);
  if (modelUrl) {
    model = new RobotView();
    dialog.querySelector('[data-trial-model]').append(model.root);
    const showing = model.show(modelUrl, spawnUrl(study, trial));
    if (names.includes('replay.json')) {
      const view = model;
      Promise.all([showing, getJSON(`/api/v1/trials/${trial.id}/artifacts/replay.json`)])
        .then(([, replay]) => view.setReplay(replay))
        .catch((error) => view.note(`No replay: ${error.message}`));
    }
  }
  const image = dialog.querySelector('[data-trial-image]');
  if (image) image.src = `/api/v1/trials/${trial.id}/artifacts/robot.png`;
  const canvas = dialog.querySelector('[data-curve]');
  if (canvas) {
    const curve = await getJSON(`/api/v1/trials/${trial.id}/artifacts/curve.json`);
    drawCurve(canvas, curve);
    const said = dialog.querySelector('[data-curve-score]');
    said.hidden = typeof curve?.score !== 'string';
    said.textContent = said.hidden ? '' : `score: ${curve.score}`;
  }
  return trial;
}
