// HTTP helpers: JSON and text reads, and the sign-in session.
// With auth on, the page signs in once: the token is sent to POST /api/v1/session, which
// answers with an HttpOnly cookie. The page never keeps the token (no storage, no URL);
// it keeps only the session's CSRF token, in memory, for the few changes it makes.

let csrfToken = null;
let session = null;

export class HttpError extends Error {
  constructor(status, detail) {
    super(`HTTP ${status}: ${detail}`);
    this.status = status;
    this.detail = detail;
  }
}

async function request(path, options = {}) {
  const response = await fetch(path, { cache: 'no-store', credentials: 'same-origin', ...options });
  if (!response.ok) {
    let detail = response.statusText;
    try {
      detail = (await response.json()).detail ?? detail;
    } catch {
      /* not JSON */
    }
    throw new HttpError(response.status, detail);
  }
  return response;
}

/** GET a JSON body; `withTotal` also returns the X-Total-Count header. */
export async function getJSON(path, { withTotal = false } = {}) {
  const response = await request(path);
  const body = await response.json();
  if (!withTotal) return body;
  return { body, total: Number(response.headers.get('X-Total-Count') ?? body.length) };
}

/** GET a text body (a URDF). */
export async function getText(path) {
  return (await request(path)).text();
}

/** The artifact names of some trials of a study: {trial id: [names]}. */
export async function artifactNames(studyId, trialIds) {
  if (trialIds.length === 0) return {};
  return getJSON(`/api/v1/dashboard/studies/${studyId}/artifacts?trial_ids=${trialIds.join(',')}`);
}

function remember(info) {
  csrfToken = info.csrf_token ?? null;
  session = info;
  return info;
}

/** What a change sends to show it comes from this page: the session's CSRF token when
 * signed in, else the header no cross-site form can send. */
function changeHeaders() {
  return csrfToken ? { 'X-CSRF-Token': csrfToken } : { 'X-Activedesign-Client': 'dashboard' };
}

/** Whether the signed-in caller may change `study` (stop, delete): anyone with auth off,
 * an admin, or a user token of the name that created it. The server checks again. */
export function mayManage(study) {
  if (!session || !session.auth) return Boolean(session);
  if (session.role === 'admin') return true;
  return session.role === 'user' && Boolean(session.name) && session.name === study.created_by;
}

/** Stop a study: no more proposals or leases, its queued trials dropped as failed, its
 * running ones left to finish. Resolves to the study as it is now. */
export async function stopStudy(studyId) {
  const response = await request(`/api/v1/studies/${studyId}/stop`, {
    method: 'POST',
    headers: changeHeaders(),
  });
  return response.json();
}

/** Replace a note (a study's or a trial's: its URL); resolves to the note as stored. */
export async function saveNote(path, text) {
  const response = await request(path, {
    method: 'PUT',
    headers: { ...changeHeaders(), 'Content-Type': 'application/json' },
    body: JSON.stringify({ text }),
  });
  return response.json();
}

/** Delete a study; `force` also cancels the leases workers hold on its trials. */
export async function deleteStudy(studyId, { force = false } = {}) {
  const query = force ? '?force=true' : '';
  await request(`/api/v1/studies/${studyId}${query}`, { method: 'DELETE', headers: changeHeaders() });
}

/** Who the page is signed in as: {auth, signed_in, role, name}. */
export async function currentSession() {
  return remember(await getJSON('/api/v1/session'));
}

/** Exchange a token for the session cookie; the token is not kept anywhere. */
export async function signIn(token) {
  const response = await request('/api/v1/session', {
    method: 'POST',
    headers: { 'Content-Type': 'application/json' },
    body: JSON.stringify({ token: token.trim() }),
  });
  return remember(await response.json());
}

export async function signOut() {
  await request('/api/v1/session', { method: 'DELETE', headers: changeHeaders() });
  csrfToken = null;
}
