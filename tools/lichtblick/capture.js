// Opens one log in the served Lichtblick web app with a layout, in headless Debian Chromium
// driven by playwright-core (never a downloaded browser), and screenshots it (1600 x 1000).
// usage: node capture.js LOG_PATH OUT.png [TIME_RFC3339] [LAYOUT_PATH|none]
// LOG_PATH and LAYOUT_PATH are paths on the server of serve.js; WAIT_MS (default 40000) is how
// long the app gets to read the log before the shot; TAB=Alerts|Topics opens that sidebar tab.
const build = process.env.LICHTBLICK_BUILD || "/work/licht-build";
const { chromium } = require(require.resolve("playwright-core", { paths: [build] }));
const base = process.env.LICHTBLICK_URL || "http://127.0.0.1:8765";
const [logPath, out, time, layout] = process.argv.slice(2);
(async () => {
  const browser = await chromium.launch({
    executablePath: "/usr/bin/chromium",
    args: ["--no-sandbox", "--disable-gpu", "--disable-background-networking",
           "--disable-component-update", "--disable-sync", "--no-first-run",
           // WebGL on the CPU: the 3-D panel needs it, and there is no GPU
           "--enable-unsafe-swiftshader", "--use-angle=swiftshader"],
  });
  const page = await browser.newPage({ viewport: { width: 1600, height: 1000 } });
  page.on("pageerror", (e) => console.error("pageerror:", String(e).slice(0, 300)));
  const q = new URLSearchParams({ ds: "remote-file", "ds.url": `${base}/${logPath}` });
  if (layout !== "none") q.set("layoutUrl", `${base}/${layout || "layout.json"}`);
  if (time) q.set("time", time);
  await page.goto(`${base}/index.html?${q}`, { waitUntil: "load" });
  await page.waitForTimeout(Number(process.env.WAIT_MS || 40000));
  if (process.env.TAB) {
    await page.getByText(process.env.TAB, { exact: true }).first().click();
    await page.waitForTimeout(1500);
    console.log((await page.locator("body").innerText()).slice(0, 3000));
  }
  await page.screenshot({ path: out });
  console.log("wrote", out);
  await browser.close();
})().catch((e) => { console.error(e); process.exit(1); });
