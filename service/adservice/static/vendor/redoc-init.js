// Starts ReDoc on /redoc. A file, not an inline script, so the page works under the
// server's Content-Security-Policy (script-src 'self'). Search is off: ReDoc runs it in
// a worker built from a blob: URL, which that policy refuses.
const root = document.getElementById('redoc');
Redoc.init(root.dataset.openapi, { disableSearch: true }, root);
