// Serves a built Lichtblick web app, our logs and the layouts on 127.0.0.1 (docs/replay.md,
// "Lichtblick"), with HTTP Range requests, which Lichtblick's remote-file source needs.
// usage: node serve.js SITE_DIR [PORT]   (LICHTBLICK_BUILD: the folder holding node_modules)
const http = require("http");
const build = process.env.LICHTBLICK_BUILD || "/work/licht-build";
const handler = require(require.resolve("serve-handler", { paths: [`${build}/lichtblick`] }));
const [root, portArg] = process.argv.slice(2);
const port = Number(portArg || 8765);
// cleanUrls off: a redirect of /index.html to / would drop the query that names the log
http.createServer((req, res) => handler(req, res, { public: root, cleanUrls: false }))
  .listen(port, "127.0.0.1", () => console.log(`serving ${root} on http://127.0.0.1:${port}`));
