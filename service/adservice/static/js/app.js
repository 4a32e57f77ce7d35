// The dashboard: a studies list (#/) and a study page (#/studies/ID), kept current by
// polling. This module routes between them and polls; each panel is its own module
// (header, history, pareto, params, best, workers, trials, trial-dialog, robot-view), composed
// by study.js.

import { HttpError } from './api.js';
import { esc } from './html.js';
import { setLive, showError } from './shell.js';
import { bindSignIn, checkSession } from './signin.js';
import { StudiesPage } from './studies.js';
import { StudyPage } from './study.js';

const POLL_MS = 2000;

const view = document.querySelector('[data-view]');
let page = null;

const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

async function route() {
  page?.stop();
  const match = window.location.hash.match(/^#\/studies\/(\d+)/);
  const current = match ? new StudyPage(view, Number(match[1])) : new StudiesPage(view);
  page = current;
  try {
    await current.start();
    current.ready = true;
    setLive(true);
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
