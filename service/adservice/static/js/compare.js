// Studies side by side (#/compare?ids=1,2): two or more studies' best value so far by
// trial on one chart and their empirical distributions on another, one colour each. The
// studies list's checkboxes open it; its own checkboxes add or drop a study (a new
// history entry each, so Back and Forward step through the comparisons).

import { getJSON } from './api.js';
import { drawXAxis, drawYAxis, extent, message, prepare } from './charts.js';
import { LINE_COLOURS, drawEdf } from './edf.js';
import { element, esc } from './html.js';
import { Series } from './series.js';
import { setCrumbs } from './shell.js';

/** The address of a comparison of `ids`. */
export function compareAddress(ids) {
  return `#/compare?ids=${ids.join(',')}`;
}

/** A study's score direction (a study of several objectives: its first objective's). */
function directionOf(study) {
  return study.directions?.[0] ?? study.direction;
}

/** Each complete (feasible) trial's best score so far: [[number, best]]. */
function bestSoFar(series, direction) {
  const better = direction === 'maximize' ? (a, b) => a > b : (a, b) => a < b;
  const steps = [];
  let best = null;
  for (const i of series.complete) {
    if (series.feasible?.[i] === false) continue;
    const value = series.value[i];
    if (best === null || better(value, best)) best = value;
    steps.push([series.number[i], best]);
  }
  return steps;
}

/** The best-so-far lines of each study on one chart. Leaves `data-lines` (JSON: each
 * study's id and its steps) for the browser tests. */
function drawBestHistories(canvas, lines) {
  const { ctx, width, height } = prepare(canvas);
  canvas.dataset.lines = JSON.stringify(lines.map((l) => ({ id: l.id, steps: l.steps })));
  const all = lines.flatMap((l) => l.steps);
  if (all.length === 0) {
    message(ctx, width, height, 'No complete trials yet');
    return;
  }
  const pad = { left: 50, right: 12, top: 10, bottom: 24 };
  const right = width - pad.right;
  const bottom = height - pad.bottom;
  const xHigh = Math.max(1, ...all.map(([n]) => n));
  const [low, high] = extent(all.map(([, v]) => v));
  const x = (n) => pad.left + (n / xHigh) * (right - pad.left);
  const y = (v) => bottom - ((v - low) / (high - low)) * (bottom - pad.top);
  drawYAxis(ctx, pad.left, pad.top, bottom, right, low, high, y);
  drawXAxis(ctx, pad.left, right, bottom, 0, xHigh, x, true);
  lines.forEach((line, k) => {
    if (line.steps.length === 0) return;
    ctx.strokeStyle = LINE_COLOURS[k % LINE_COLOURS.length];
    ctx.lineWidth = 2;
    ctx.beginPath();
    let [number, best] = line.steps[0];
    ctx.moveTo(x(number), y(best));
    for (const [n, v] of line.steps.slice(1)) {
      ctx.lineTo(x(n), y(best));
      ctx.lineTo(x(n), y(v));
      [number, best] = [n, v];
    }
    ctx.lineTo(x(line.last), y(best));
    ctx.stroke();
  });
  ctx.lineWidth = 1;
}

export class ComparePage {
  constructor(view, ids) {
    this.ids = ids;
    this.alive = true;
    this.studies = [];
    this.series = new Map(ids.map((id) => [id, new Series(id)]));
    this.root = element(`<div class="compare" data-compare>
      <section class="card"><h2>Compare studies</h2>
        <p class="meta" data-compare-note></p>
        <div class="compare-picks" data-compare-picks></div>
        <ul class="compare-legend" data-compare-legend></ul></section>
      <section class="card"><h2>Best value so far <span class="legend">by trial number</span></h2>
        <canvas class="chart" data-compare-history></canvas></section>
      <section class="card"><h2>Empirical distribution
        <span class="legend">fraction of complete trials with a score ≤ x</span></h2>
        <canvas class="chart" data-compare-edf></canvas></section>
    </div>`);
    view.replaceChildren(this.root);
    this.root.querySelector('[data-compare-picks]').addEventListener('change', (event) => {
      const box = event.target.closest('input[data-pick]');
      if (!box) return;
      const id = Number(box.dataset.pick);
      const ids = box.checked ? [...this.ids, id] : this.ids.filter((other) => other !== id);
      window.location.hash = compareAddress(ids);
    });
    document.title = 'Compare studies · activedesign';
    setCrumbs('<span>compare</span>');
  }

  async start() {
    await this.poll();
    this.root.dataset.ready = 'true';
  }

  async poll() {
    const all = await getJSON('/api/v1/studies');
    const byId = new Map(all.map((s) => [s.id, s]));
    await Promise.all(this.ids.filter((id) => byId.has(id)).map((id) => this.series.get(id).load()));
    if (!this.alive) return;
    this.studies = this.ids.map((id) => byId.get(id)).filter(Boolean);
    const missing = this.ids.filter((id) => !byId.has(id));
    this.render(all, missing);
  }

  render(all, missing) {
    const picks = all
      .slice()
      .sort((a, b) => b.id - a.id)
      .map(
        (s) => `<label><input type="checkbox" data-pick="${s.id}" ${this.ids.includes(s.id) ? 'checked' : ''}>
          ${esc(s.name)} <span class="meta">#${s.id}</span></label>`,
      )
      .join('');
    this.root.querySelector('[data-compare-picks]').innerHTML = picks;
    const note = [];
    if (this.studies.length < 2) note.push('Pick two or more studies to compare.');
    if (missing.length) note.push(`No study ${missing.map((id) => `#${id}`).join(', ')}.`);
    this.root.querySelector('[data-compare-note]').textContent = note.join(' ');
    this.root.querySelector('[data-compare-legend]').innerHTML = this.studies
      .map(
        (s, k) => `<li data-compared="${s.id}"><i style="background:${LINE_COLOURS[k % LINE_COLOURS.length]}"></i>
          <a href="#/studies/${s.id}">${esc(s.name)}</a> <span class="meta">#${s.id} ·
          ${directionOf(s) === 'maximize' ? 'maximise' : 'minimise'} · ${s.n_complete} complete</span></li>`,
      )
      .join('');
    const lines = this.studies.map((s) => {
      const series = this.series.get(s.id);
      return {
        id: s.id,
        steps: bestSoFar(series, directionOf(s)),
        last: series.number.length ? series.number[series.number.length - 1] : 0,
      };
    });
    drawBestHistories(this.root.querySelector('[data-compare-history]'), lines);
    drawEdf(
      this.root.querySelector('[data-compare-edf]'),
      this.studies.map((s) => {
        const series = this.series.get(s.id);
        return { label: `#${s.id}`, values: series.complete.map((i) => series.value[i]) };
      }),
    );
  }

  stop() {
    this.alive = false;
  }
}
