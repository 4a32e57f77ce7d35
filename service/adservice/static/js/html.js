// Markup helpers the panels share: escaping, elements from markup, times, params, links.

import { formatNumber } from './charts.js';

export function esc(text) {
  return String(text ?? '').replace(
    /[&<>"']/g,
    (c) => ({ '&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;', "'": '&#39;' })[c],
  );
}

export function element(html) {
  const template = document.createElement('template');
  template.innerHTML = html.trim();
  return template.content.firstElementChild;
}

/** `$('name')` finds `[data-name]` inside `root` only: a panel never reaches another's. */
export function finder(root) {
  return (name) => root.querySelector(`[data-${name}]`);
}

export function badge(state) {
  return `<span class="badge ${esc(state)}">${esc(state)}</span>`;
}

export function ago(iso) {
  if (!iso) return '—';
  const seconds = (Date.now() - Date.parse(iso)) / 1000;
  if (seconds < 2) return 'just now';
  if (seconds < 60) return `${Math.round(seconds)} s ago`;
  if (seconds < 3600) return `${Math.round(seconds / 60)} min ago`;
  if (seconds < 86400) return `${Math.round(seconds / 3600)} h ago`;
  return new Date(iso).toLocaleString();
}

export function when(iso) {
  return iso ? `<span title="${esc(iso)}">${new Date(iso).toLocaleString()}</span>` : '—';
}

function seconds(value) {
  if (value < 1) return `${Math.round(value * 1000)} ms`;
  if (value < 60) return `${value.toFixed(1)} s`;
  if (value < 3600) return `${Math.floor(value / 60)} min ${Math.round(value % 60)} s`;
  return `${Math.floor(value / 3600)} h ${Math.round((value % 3600) / 60)} min`;
}

export function duration(trial) {
  if (!trial.started_at) return '—';
  const end = trial.finished_at ? Date.parse(trial.finished_at) : Date.now();
  const text = seconds(Math.max(0, end - Date.parse(trial.started_at)) / 1000);
  return trial.finished_at ? text : `${text}…`;
}

export function formatParam(value) {
  if (typeof value === 'number') return formatNumber(value);
  if (Array.isArray(value)) return `[${value.map(formatParam).join(', ')}]`;
  return String(value);
}

/** A user attribute's value as text: strings as they are, anything else as JSON. */
export function attrText(value) {
  return typeof value === 'string' ? value : JSON.stringify(value);
}

/** Key-value rows of user attributes, built as text nodes. */
export function attrsTable(attrs) {
  const table = document.createElement('table');
  table.className = 'kv';
  table.dataset.userAttrs = '';
  for (const [key, value] of Object.entries(attrs)) {
    const name = document.createElement('th');
    name.textContent = key;
    const row = table.insertRow();
    row.append(name);
    row.insertCell().textContent = attrText(value);
  }
  return table;
}

export function paramsTable(params) {
  const rows = Object.entries(params ?? {})
    .map(([k, v]) => `<tr><th>${esc(k)}</th><td>${esc(formatParam(v))}</td></tr>`)
    .join('');
  return `<table class="kv">${rows}</table>`;
}

/** Where a trial's URDF is: decoded by the server for a design study, else the worker's
 * robot.urdf artifact if it uploaded one (null if none). */
export function urdfUrl(study, trial, artifacts) {
  if (study.space?.type && study.space.type !== 'box') return `/api/v1/trials/${trial.id}/urdf`;
  if (artifacts.includes('robot.urdf')) return `/api/v1/trials/${trial.id}/artifacts/robot.urdf`;
  return null;
}

/** Where the simulator starts a trial's robot (`GET /api/v1/trials/{id}/spawn`): for a
 * design or template study run by one of the server's tasks (null for any other). */
export function spawnUrl(study, trial) {
  const robot = study.space?.type === 'design' || study.space?.type === 'template';
  return robot && study.task && !study.task.external ? `/api/v1/trials/${trial.id}/spawn` : null;
}

export function urdfLink(study, trial, artifacts, label = 'URDF') {
  const url = urdfUrl(study, trial, artifacts);
  if (!url) return '';
  const file = `trial-${trial.number}.urdf`;
  return `<a href="${url}" download="${file}" data-download="${file}">${label}</a>`;
}

/** The score's spread over a trial's evaluation episodes (each on a seed of its own), as
 * its worker reported it (metrics score_std, score_min, score_max, eval_episodes), as a
 * mark to put beside the score: `± 0.012`, the rest in its title. Empty when the trial's
 * metrics do not carry it. */
export function scoreSpread(trial) {
  const metrics = trial?.metrics ?? {};
  const std = metrics.score_std;
  if (typeof std !== 'number' || !Number.isFinite(std)) return '';
  const episodes = metrics.eval_episodes;
  const over = typeof episodes === 'number' ? ` over ${formatNumber(episodes)} evaluation episodes (a seed each)` : '';
  const range =
    typeof metrics.score_min === 'number' && typeof metrics.score_max === 'number'
      ? `, from ${formatNumber(metrics.score_min)} to ${formatNumber(metrics.score_max)}`
      : '';
  const title = `standard deviation of the score${over}${range}`;
  return ` <span class="spread-mark" data-score-spread="${std}" title="${esc(title)}">± ${esc(formatNumber(std))}${episodes ? ` <span class="meta">(${formatNumber(episodes)} ep.)</span>` : ''}</span>`;
}
