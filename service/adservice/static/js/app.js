// The dashboard: a studies list (#/), a study page (#/studies/ID; a trial's dialog at
// #/studies/ID/trials/N) and a comparison of studies (#/compare?ids=1,2), kept current by
// polling. This module routes between them and
// polls; each panel is its own module (header, history, pareto, params, best, workers,
// trials, trial-dialog, robot-view), composed by study.js.

import { HttpError } from './api.js';
import { esc } from './html.js';
import { setLive, showError } from './shell.js';
import { bindSignIn, checkSession } from './signin.js';
import { StudiesPage } from './studies.js';
import { StudyPage } from './study.js';
import { ComparePage } from './compare.js';
import { closeTrialDialog } from './trial-dialog.js';

const POLL_MS = 2000;

const view = document.querySelector('[data-view]');
let page = null;

const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

/** The studies a comparison's address names (#/compare?ids=1,2), in its order, each once;
 * null for another address. */
function comparedIds() {
  const match = window.location.hash.match(/^#\/compare(?:\?ids=([\d,]*))?$/);
  if (!match) return null;
  const ids = (match[1] ?? '').split(',').filter(Boolean).map(Number);
  return [...new Set(ids)];
}

/** The address's study and trial: #/studies/ID, #/studies/ID/trials/N, or neither. */
function place() {
  const match = window.location.hash.match(/^#\/studies\/(\d+)(?:\/trials\/(\d+))?/);
  return {
    studyId: match ? Number(match[1]) : null,
    trialNumber: match?.[2] !== undefined ? Number(match[2]) : null,
  };
}

async function route() {
  const { studyId, trialNumber } = place();
  const same = page instanceof StudyPage && page.studyId === studyId;
  if (same && page.alive && page.ready && !page.gone) {
    page.showTrial(trialNumber); // the same study: only its dialog opens or closes
    return;
  }
  closeTrialDialog();
  page?.stop();
  const compared = comparedIds();
  let current;
  if (compared !== null) current = new ComparePage(view, compared);
  else current = studyId !== null ? new StudyPage(view, studyId) : new StudiesPage(view);
  page = current;
  try {
    await current.start();
    current.ready = true;
    setLive(true);
    const named = place(); // the address now: it may have moved while the page loaded
    if (page === current && named.studyId === studyId && named.trialNumber !== null) {
      current.showTrial(named.trialNumber);
    }
  } catch (error) {
    if (error instanceof HttpError && error.status === 404) {
      current.gone = true;
      view.innerHTML = `<section class="card"><h2>Not found</h2><p>${esc(error.message)}</p>
        <p><a href="#/">All studies</a></p></section>`;
    }
    showError(error);
  }
}

async function pollForever() {
  for (;;) {
    await sleep(POLL_MS);
    const current = page;
    if (document.hidden || !current || current.gone) continue;
    try {
      if (current.ready) await current.poll();
      else await route(); // the first load failed (server down, no token): try again
      setLive(true);
    } catch (error) {
      showError(error);
    }
  }
}

async function start() {
  bindSignIn({
    signedIn: route,
    signedOut: () => {
      page?.stop();
      closeTrialDialog();
      view.innerHTML = '';
    },
  });
  try {
    await checkSession();
  } catch (error) {
    showError(error);
  }
  window.addEventListener('hashchange', route);
  route();
  pollForever();
}

start();
