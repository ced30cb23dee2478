// Opens the viewer in headless Chromium (the system's binary, driven by playwright-core; no browser is
// downloaded) and reports what the page shows, for the browser test of the viewer.
//
//   node drive.mjs URL [--chromium PATH] [--width 1600] [--height 1000] [--every-ms 1000]
//
// stdout, one JSON object a line:
//   {"kind": "launch-failed", "error": "..."}             Chromium did not start (exit code 3)
//   {"kind": "state", "panels": [...], "diagnostics": [...], "okColor": "..."}  every --every-ms: per
//        panel its id in the layout, its text, for plots the legend's entries, for tables the rows'
//        cells, outside: the rows (and the pager) that lie outside the panel, box: where the panel is on the page
//        ({x, y, width, height}, CSS px, as in a screenshot); the diagnostics panel's rows; connectionLost: the
//        viewer's "no connection" bar's text ("" if hidden); dialog: the text of any dialog over the app
//   {"kind": "problem", "text": "..."}                     the app reported a data source problem
//   {"kind": "screenshot", "path": "..."}                  after a `screenshot PATH` line on stdin
//   {"kind": "page-error", "error": "..."}                 an uncaught error in the page
//   {"kind": "external-request", "url": "..."}             the page asked for something off this machine
//   {"kind": "http-error", "url": "...", "status": 404}     a request the server answered with an error
//   {"kind": "ranged", "url": "...", "range": "bytes=0-99", "status": 206}  a request with a Range header, answered
// stdin, one command a line: `screenshot PATH`, `quit`.
import { createInterface } from "node:readline";

import { chromium } from "playwright-core";

function option(name, fallback) {
  const i = process.argv.indexOf(name);
  return i > 0 ? process.argv[i + 1] : fallback;
}

const url = process.argv[2];
const executablePath = option("--chromium", "/usr/bin/chromium");
const width = Number(option("--width", "1600"));
const height = Number(option("--height", "1000"));
const everyMs = Number(option("--every-ms", "1000"));
const say = (obj) => process.stdout.write(JSON.stringify(obj) + "\n");

// What the page shows, read from the DOM (runs in the page). Each panel's element names the panel's id
// in the layout (a data-testid, "panel-mouseenter-container Plot!livetrace"). A plot's legend (with values shown) has, per series, the label and the
// value right-aligned beside it. The diagnostics panel's rows carry a data-testid attribute; a row's
// level shows only as the colour of its message, so the colour of the level filter's "OK" comes along.
function readPage() {
  const panels = [];
  for (const win of document.querySelectorAll("[data-testid^='panel-mouseenter-container ']")) {
    const text = win.innerText.trim();
    const id = win.dataset.testid.split(" ")[1];
    const legend = [...win.querySelectorAll(".MuiTypography-alignRight")].map((el) => ({
      label: el.parentElement?.previousElementSibling?.innerText.trim() ?? "",
      value: el.innerText.trim(),
    }));
    // a Table panel's rows (the first is the header), cell by cell
    const table = [...win.querySelectorAll("tr")].map((tr) => [...tr.children].map((cell) => cell.innerText.trim()));
    // what of the panel lies outside it (cut off, or to be scrolled to): table rows, the pager, the Nodes tab's rows
    const box = win.getBoundingClientRect();
    // the pager: the innermost element that reads "Page 1 of 1"
    const pager = [...win.querySelectorAll("*")].filter((el) => /^Page \d+ of \d+$/.test(el.innerText?.trim() ?? "") &&
      ![...el.children].some((child) => /^Page \d+ of \d+$/.test(child.innerText?.trim() ?? "")));
    const parts = [...win.querySelectorAll("tr, [data-testid-diagnostic-row]"), ...pager];
    const outside = parts.filter((el) => {
      const r = el.getBoundingClientRect();
      return r.height > 0 && (r.bottom > box.bottom + 1 || r.top < box.top - 1);
    }).map((el) => el.innerText.trim().slice(0, 60));
    panels.push({ id, text, legend, table, outside,
      box: { x: box.x, y: box.y, width: box.width, height: box.height } });
  }
  const diagnostics = [...document.querySelectorAll("[data-testid-diagnostic-row]")].map((row) => {
    const secondary = row.querySelector(".MuiListItemText-secondary");
    return {
      name: row.querySelector(".MuiListItemText-primary")?.innerText.trim() ?? "",
      message: secondary?.innerText.trim() ?? "",
      color: secondary ? getComputedStyle(secondary).color : "",
    };
  });
  const filter = document.querySelector("#status-filter-menu .MuiListItemText-primary");
  const okColor = filter && filter.innerText.trim() === "OK" ? getComputedStyle(filter).color : "";
  const banner = document.getElementById("connection-lost");
  const connectionLost = banner && banner.style.display !== "none" ? banner.innerText.trim() : "";
  // a dialog over the app (Studio's start-up "open data source" dialog), its first words ("" if none)
  const dialog = [...document.querySelectorAll("[role=dialog]")].map((d) => d.innerText.trim().slice(0, 80)).join(" | ");
  return { panels, diagnostics, okColor, connectionLost, dialog };
}

let browser;
try {
  browser = await chromium.launch({
    executablePath,
    headless: true,
    args: ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
      "--disable-sync", "--no-first-run", "--disable-default-apps"],
  });
} catch (error) {
  say({ kind: "launch-failed", error: String(error).split("\n")[0] });
  process.exit(3);
}
const page = await browser.newPage({ viewport: { width, height } });
page.on("pageerror", (error) => say({ kind: "page-error", error: String(error).slice(0, 500) }));
// the viewer must need no internet: every request stays on this machine (or in the page: data:, blob:)
page.on("request", (request) => {
  const { protocol, hostname } = new URL(request.url());
  if (!["data:", "blob:"].includes(protocol) && !["127.0.0.1", "localhost", "[::1]"].includes(hostname)) {
    say({ kind: "external-request", url: request.url() });
  }
});
// a request the viewer's server answered with an error (a file the page wants and the site lacks)
page.on("response", (response) => {
  if (response.status() >= 400) {
    say({ kind: "http-error", url: response.url(), status: response.status() });
  }
  const range = response.request().headers()["range"];
  if (range) {
    say({ kind: "ranged", url: response.url(), range, status: response.status() });
  }
});
// the app logs each problem of its data source ("Player problem ws:connection-failed {...}")
page.on("console", (message) => {
  if (message.text().startsWith("Player problem")) {
    say({ kind: "problem", text: message.text().slice(0, 500) });
  }
});
await page.goto(url);

let busy = false;
const timer = setInterval(async () => {
  if (busy) return;
  busy = true;
  try {
    say({ kind: "state", ...(await page.evaluate(readPage)) });
  } catch (error) {
    say({ kind: "page-error", error: String(error).slice(0, 500) });
  } finally {
    busy = false;
  }
}, everyMs);

for await (const line of createInterface({ input: process.stdin })) {
  const [command, ...rest] = line.trim().split(" ");
  if (command === "screenshot") {
    const path = rest.join(" ");
    await page.screenshot({ path });
    say({ kind: "screenshot", path });
  } else if (command === "quit") {
    break;
  }
}
clearInterval(timer);
await browser.close();
