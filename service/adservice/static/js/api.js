// HTTP helpers: JSON reads, blobs for images and downloads, and the optional bearer token.
// The token is the user's own (never part of the page): it is taken once from `?token=`
// and kept in localStorage under 'ad_token'.

const TOKEN_KEY = 'ad_token';

export class HttpError extends Error {
  constructor(status, detail) {
    super(`HTTP ${status}: ${detail}`);
    this.status = status;
  }
  get isAuth() {
    return this.status === 401 || this.status === 403;
  }
}

/** Move a `?token=` from the address into localStorage, and out of the address bar. */
export function adoptTokenFromUrl() {
  const url = new URL(window.location.href);
  const token = url.searchParams.get('token');
  if (token) {
    setToken(token);
    url.searchParams.delete('token');
    history.replaceState(null, '', url.pathname + url.search + url.hash);
  }
}

export function setToken(token) {
  if (token) localStorage.setItem(TOKEN_KEY, token.trim());
  else localStorage.removeItem(TOKEN_KEY);
}

export function hasToken() {
  return Boolean(localStorage.getItem(TOKEN_KEY));
}

function headers() {
  const token = localStorage.getItem(TOKEN_KEY);
  return token ? { Authorization: `Bearer ${token}` } : {};
}

async function request(path) {
  const response = await fetch(path, { headers: headers(), cache: 'no-store' });
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

/** GET a file as an object URL (works with a bearer token, unlike a bare <img src>). */
export async function getObjectUrl(path) {
  const response = await request(path);
  return URL.createObjectURL(await response.blob());
}

/** Links marked `data-download` fetch with the token and save, when a token is set;
 * without one they are plain links. */
export function installDownloadLinks(root) {
  root.addEventListener('click', async (event) => {
    const link = event.target.closest('a[data-download]');
    if (!link || !hasToken()) return;
    event.preventDefault();
    const url = await getObjectUrl(link.getAttribute('href'));
    const save = document.createElement('a');
    save.href = url;
    save.download = link.dataset.download;
    save.click();
    setTimeout(() => URL.revokeObjectURL(url), 10_000);
  });
}
