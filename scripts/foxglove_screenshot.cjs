#!/usr/bin/env node
// A screenshot of an RRG bag in Foxglove Studio with docs/foxglove/rrg_layout.json, taken offline
// with a headless browser. The app is the open-source Foxglove Studio (npm @foxglove/studio-base
// 1.48.0, its web build, with React 17), served from this machine at 127.0.0.1 together with the
// bag (HTTP range requests, as Foxglove's "Remote file" data source reads it) and the layout;
// Debian's Chromium, driven by playwright-core, opens it, waits until the panels have drawn and
// saves a PNG. Installs: scripts/setup_foxglove.sh.
//
//   node scripts/foxglove_screenshot.cjs BAG [--out docs/img/foxglove_layout.png]
//        [--layout docs/foxglove/rrg_layout.json] [--at SECONDS] [--size 1600x1000]
//        [--wait SECONDS] [--serve]
//
// BAG: a bag folder (its first .mcap) or an .mcap file. --at: the playback time to show, in
// seconds from the bag's start (default: when the simulator's grasp outcome was logged, so the
// plots hold the whole grasp). --serve: print the URL and keep serving (open it in a browser)
// instead of taking a screenshot.
"use strict";
const fs = require("fs");
const http = require("http");
const path = require("path");

const ROOT = path.resolve(__dirname, "..");
const MODULES = process.env.RRG_FOXGLOVE_MODULES || path.join(ROOT, ".cache", "foxglove", "node_modules");
const CHROMIUM = process.env.RRG_CHROMIUM || "/usr/bin/chromium";
const LAYOUT_ID = "rrg-layout";
const OUTCOME_TOPIC = "/rrg/eval/grasp_outcome";

function usage(msg) {
  process.stderr.write(`foxglove_screenshot: ${msg}\n`);
  process.exit(2);
}

function parseArgs(argv) {
  const opts = {
    out: path.join(ROOT, "docs", "img", "foxglove_layout.png"),
    layout: path.join(ROOT, "docs", "foxglove", "rrg_layout.json"),
    at: undefined,
    width: 1600,
    height: 1000,
    wait: 8,
    serve: false,
  };
  const rest = [];
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    const value = () => {
      if (i + 1 >= argv.length) usage(`${a} needs a value`);
      return argv[++i];
    };
    if (a === "--out") opts.out = path.resolve(value());
    else if (a === "--layout") opts.layout = path.resolve(value());
    else if (a === "--at") opts.at = Number(value());
    else if (a === "--wait") opts.wait = Number(value());
    else if (a === "--size") [opts.width, opts.height] = value().split("x").map(Number);
    else if (a === "--serve") opts.serve = true;
    else if (a.startsWith("--")) usage(`unknown option ${a}`);
    else rest.push(a);
  }
  if (rest.length !== 1) usage("give one bag (a folder or an .mcap file)");
  let bag = path.resolve(rest[0]);
  if (!fs.existsSync(bag)) usage(`no such bag: ${bag}`);
  if (fs.statSync(bag).isDirectory()) {
    const files = fs.readdirSync(bag).filter((f) => f.endsWith(".mcap")).sort();
    if (files.length === 0) usage(`no .mcap file in ${bag}`);
    bag = path.join(bag, files[0]);
  }
  opts.bag = bag;
  if (![opts.width, opts.height, opts.wait].every((n) => Number.isFinite(n) && n > 0)) {
    usage("--size and --wait take positive numbers");
  }
  return opts;
}

// The bag's start and end [ns] and the log time [ns] of its last grasp outcome (undefined: none).
async function bagTimes(file) {
  const { McapIndexedReader } = require(path.join(MODULES, "@mcap/core"));
  const fd = fs.openSync(file, "r");
  const size = BigInt(fs.fstatSync(fd).size);
  const readable = {
    size: async () => size,
    read: async (offset, length) => {
      const buf = Buffer.alloc(Number(length));
      fs.readSync(fd, buf, 0, Number(length), Number(offset));
      return new Uint8Array(buf.buffer, buf.byteOffset, buf.byteLength);
    },
  };
  const reader = await McapIndexedReader.Initialize({ readable });
  const stats = reader.statistics;
  let outcome;
  for await (const msg of reader.readMessages({ topics: [OUTCOME_TOPIC] })) outcome = msg.logTime;
  fs.closeSync(fd);
  return { start: stats.messageStartTime, end: stats.messageEndTime, outcome };
}

function rfc3339(ns) {
  const ms = Number(ns / 1000000n);
  const frac = String(ns % 1000000000n).padStart(9, "0");
  return new Date(ms).toISOString().replace(/\.\d{3}Z$/, `.${frac}Z`);
}

// The page: React 17 and Foxglove Studio's web build, the bag as a "Remote file" (deep link
// ds=remote-file), the layout from a layout storage holding just it (deep link layoutId).
const PAGE = `<!doctype html>
<html><head><meta charset="utf-8"><title>RRG bag in Foxglove Studio</title>
<style>html, body, #root { height: 100%; margin: 0; }</style></head>
<body><div id="root"></div>
<script src="/vendor/react.js"></script>
<script src="/vendor/react-dom.js"></script>
<script>window.react = window.React; window["react-dom"] = window.ReactDOM;</script>
<script src="/assets/index.js"></script>
<script>
(async () => {
  const S = window;  // the UMD build puts its exports on the global object
  // the panels, not the data source's sidebar; no onboarding tooltip over the 3D panel
  if (localStorage.getItem("fox.workspace") == undefined) {
    localStorage.setItem("fox.workspace", JSON.stringify({
      state: { sidebarItem: null, leftSidebarOpen: false, rightSidebarOpen: false }, version: 0,
    }));
  }
  if (localStorage.getItem("studio.profile-data") == undefined) {
    localStorage.setItem("studio.profile-data", JSON.stringify({
      onboarding: { settingsTooltipShownForPanelTypes: ["3D", "Plot", "StateTransitions", "Indicator", "RawMessages"] },
    }));
  }
  const layoutData = await (await fetch("/layout.json")).json();
  const now = new Date().toISOString();
  const layouts = new Map([["${LAYOUT_ID}", {
    id: "${LAYOUT_ID}", name: "RRG", permission: "CREATOR_WRITE",
    baseline: { data: layoutData, savedAt: now }, working: undefined, syncInfo: undefined,
  }]]);
  const layoutStorage = {
    list: async () => [...layouts.values()],
    get: async (_ns, id) => layouts.get(id),
    put: async (_ns, layout) => { layouts.set(layout.id, layout); return layout; },
    delete: async (_ns, id) => { layouts.delete(id); },
    importLayouts: async () => {},
    migrateUnnamespacedLayouts: async () => {},
  };
  const settings = new Map([["colorScheme", "dark"], ["timezone", "UTC"]]);
  const listeners = new Map();
  const appConfiguration = {
    get: (key) => settings.get(key),
    set: async (key, value) => { settings.set(key, value); (listeners.get(key) || []).forEach((cb) => cb(value)); },
    addChangeListener: (key, cb) => listeners.set(key, [...(listeners.get(key) || []), cb]),
    removeChangeListener: (key, cb) => listeners.set(key, (listeners.get(key) || []).filter((c) => c !== cb)),
  };
  S.overwriteFetch();
  await S.waitForFonts();
  await S.initI18n();
  window.ReactDOM.render(
    window.React.createElement(S.App, {
      deepLinks: [window.location.href],
      dataSources: [new S.RemoteDataSourceFactory(), new S.McapLocalDataSourceFactory()],
      appConfiguration,
      layoutStorage,
      extensionLoaders: [],
      enableGlobalCss: true,
    }),
    document.getElementById("root"),
  );
  window.rrgStarted = true;
})().catch((err) => { window.rrgError = String(err && err.stack || err); console.error(err); });
</script></body></html>`;

const TYPES = {
  ".js": "text/javascript",
  ".wasm": "application/wasm",
  ".png": "image/png",
  ".ttf": "font/ttf",
  ".json": "application/json",
  ".mcap": "application/octet-stream",
  ".html": "text/html; charset=utf-8",
};

// A file, whole or the byte range the request asks for (Foxglove reads the bag in ranges).
function sendFile(req, res, file) {
  let stat;
  try {
    stat = fs.statSync(file);
  } catch {
    res.writeHead(404).end();
    return;
  }
  const headers = {
    "Content-Type": TYPES[path.extname(file)] || "application/octet-stream",
    "Accept-Ranges": "bytes",
    "Access-Control-Allow-Origin": "*",
    "Access-Control-Expose-Headers": "Accept-Ranges, Content-Range, Content-Length",
  };
  const range = /^bytes=(\d*)-(\d*)$/.exec(req.headers.range || "");
  if (range && (range[1] !== "" || range[2] !== "")) {
    let start = range[1] === "" ? stat.size - Number(range[2]) : Number(range[1]);
    let end = range[1] !== "" && range[2] !== "" ? Number(range[2]) : stat.size - 1;
    start = Math.max(0, start);
    end = Math.min(end, stat.size - 1);
    if (start > end) {
      res.writeHead(416, { "Content-Range": `bytes */${stat.size}` }).end();
      return;
    }
    res.writeHead(206, {
      ...headers,
      "Content-Range": `bytes ${start}-${end}/${stat.size}`,
      "Content-Length": end - start + 1,
    });
    if (req.method === "HEAD") res.end();
    else fs.createReadStream(file, { start, end }).pipe(res);
    return;
  }
  res.writeHead(200, { ...headers, "Content-Length": stat.size });
  if (req.method === "HEAD") res.end();
  else fs.createReadStream(file).pipe(res);
}

function serve(opts) {
  const studio = path.join(MODULES, "@foxglove", "studio-base", "assets");
  const files = {
    "/vendor/react.js": path.join(MODULES, "react", "umd", "react.production.min.js"),
    "/vendor/react-dom.js": path.join(MODULES, "react-dom", "umd", "react-dom.production.min.js"),
    "/layout.json": opts.layout,
    [`/bag/${path.basename(opts.bag)}`]: opts.bag,
  };
  const server = http.createServer((req, res) => {
    const url = new URL(req.url, "http://127.0.0.1");
    const p = decodeURIComponent(url.pathname);
    if (p === "/favicon.ico") {
      res.writeHead(204).end();
    } else if (p === "/" || p === "/index.html") {
      res.writeHead(200, { "Content-Type": TYPES[".html"] }).end(PAGE);
    } else if (files[p]) {
      sendFile(req, res, files[p]);
    } else if (p.startsWith("/assets/") && !p.includes("..")) {
      sendFile(req, res, path.join(studio, p.slice("/assets/".length)));
    } else {
      res.writeHead(404).end();
    }
  });
  return new Promise((resolve) => server.listen(0, "127.0.0.1", () => resolve(server)));
}

async function main() {
  const opts = parseArgs(process.argv.slice(2));
  for (const need of ["@foxglove/studio-base/assets/index.js", "react/umd", "react-dom/umd", "playwright-core", "@mcap/core"]) {
    if (!fs.existsSync(path.join(MODULES, need))) {
      usage(`${path.join(MODULES, need)} is missing: run scripts/setup_foxglove.sh`);
    }
  }
  JSON.parse(fs.readFileSync(opts.layout, "utf8")); // a layout that does not parse fails here
  const times = await bagTimes(opts.bag);
  let at = times.outcome ?? times.end;
  if (opts.at !== undefined) at = times.start + BigInt(Math.round(opts.at * 1e9));
  if (at > times.end) at = times.end;

  const server = await serve(opts);
  const port = server.address().port;
  const bagUrl = `http://127.0.0.1:${port}/bag/${encodeURIComponent(path.basename(opts.bag))}`;
  const url =
    `http://127.0.0.1:${port}/?ds=remote-file&ds.url=${encodeURIComponent(bagUrl)}` +
    `&layoutId=${LAYOUT_ID}&time=${encodeURIComponent(rfc3339(at))}`;
  if (opts.serve) {
    process.stdout.write(`${url}\n`);
    return; // the server keeps the process alive
  }
  if (!fs.existsSync(CHROMIUM)) usage(`no Chromium at ${CHROMIUM}: run scripts/setup_foxglove.sh`);
  const { chromium } = require(path.join(MODULES, "playwright-core"));
  const browser = await chromium.launch({
    executablePath: CHROMIUM,
    args: ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist", "--no-sandbox"],
  });
  const problems = [];
  try {
    const page = await browser.newPage({ viewport: { width: opts.width, height: opts.height } });
    page.on("pageerror", (err) => problems.push(`page error: ${err.message}`));
    page.on("console", (msg) => {
      if (msg.type() === "error") problems.push(`console: ${msg.text()} ${JSON.stringify(msg.location())}`);
    });
    await page.goto(url, { waitUntil: "load", timeout: 120000 });
    await page.waitForFunction(() => window.rrgStarted || window.rrgError, null, { timeout: 120000 });
    const startError = await page.evaluate(() => window.rrgError);
    if (startError) throw new Error(`the app did not start: ${startError}`);
    // the panels exist once the layout is loaded, the 3D panel's canvas once it draws
    await page.waitForSelector("canvas", { timeout: 120000 });
    await page.waitForTimeout(opts.wait * 1000); // the bag's blocks load and the panels redraw
    fs.mkdirSync(path.dirname(opts.out), { recursive: true });
    await page.screenshot({ path: opts.out, timeout: 180000 });
    process.stdout.write(`${opts.out}: ${opts.bag} at ${rfc3339(at)} in Foxglove Studio\n`);
  } finally {
    await browser.close();
    server.close();
  }
  for (const p of problems) process.stderr.write(`foxglove_screenshot: ${p}\n`);
  if (problems.some((p) => p.startsWith("page error"))) process.exit(1);
}

main().catch((err) => {
  process.stderr.write(`foxglove_screenshot: ${err.stack || err}\n`);
  process.exit(1);
});
