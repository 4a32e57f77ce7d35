// Starts Swagger UI on /docs. A file, not an inline script, so the page works under the
// server's Content-Security-Policy (script-src 'self'). No validator badge: it would
// send the schema's URL to validator.swagger.io.
const root = document.getElementById('swagger-ui');
window.ui = SwaggerUIBundle({
  url: root.dataset.openapi,
  dom_id: '#swagger-ui',
  layout: 'BaseLayout',
  deepLinking: true,
  showExtensions: true,
  showCommonExtensions: true,
  validatorUrl: null,
  presets: [SwaggerUIBundle.presets.apis, SwaggerUIBundle.SwaggerUIStandalonePreset],
});
