// The page's frame around a view: breadcrumbs, the live dot, and errors.

import { HttpError } from './api.js';
import { ASK, askToSignIn } from './signin.js';

export function setCrumbs(html) {
  document.querySelector('[data-crumbs]').innerHTML = html ? `<span>›</span> ${html}` : '';
}

export function setLive(ok, detail = '') {
  const live = document.querySelector('[data-live]');
  live.classList.toggle('ok', ok);
  live.classList.toggle('down', !ok);
  live.title = ok ? `live · last update ${new Date().toLocaleTimeString()}` : `not updating: ${detail}`;
}

export function showError(error) {
  console.error(error);
  if (error instanceof HttpError && error.status === 401) askToSignIn(ASK);
  setLive(false, error.message);
}
