// The force tester's viewer: renders the Foxglove Studio app (loaded by index.html from
// @foxglove/studio-base's library build, whose exports are globals) with
//   - one layout, the workspace's, kept in memory and read from layout.json (so every page load starts
//     from the layout as shipped; edits last until the page is reloaded),
//   - settings kept in memory,
//   - the Foxglove WebSocket data source (the live monitor), local MCAP files (a recorded bag, "Open local
//     file") and remote files (a bag `./ft view --bag` serves from this origin, read with HTTP Range requests).
// The URL says what to open, in Studio's own deep-link parameters, which `./ft view` prints:
//   ?ds=foxglove-websocket&ds.url=ws://HOST:8765&layoutId=force-tester
//   ?ds=remote-file&ds.url=http://HOST:8080/bag/NAME.mcap&layoutId=force-tester&time=<the last message, RFC 3339>
"use strict";

const LAYOUT_ID = "force-tester";
const LAYOUT_NAME = "Force tester";

// ILayoutStorage: the layouts by id, whatever the namespace the app asks for
class MemoryLayoutStorage {
  constructor(layouts) {
    this.layouts = new Map(layouts.map((layout) => [layout.id, layout]));
  }
  async list(_namespace) {
    return [...this.layouts.values()];
  }
  async get(_namespace, id) {
    return this.layouts.get(id);
  }
  async put(_namespace, layout) {
    this.layouts.set(layout.id, layout);
    return layout;
  }
  async delete(_namespace, id) {
    this.layouts.delete(id);
  }
  async importLayouts(_params) {}
  async migrateUnnamespacedLayouts(_namespace) {}
}

// IAppConfiguration: settings in memory, with listeners per key
class MemoryAppConfiguration {
  constructor(initial) {
    this.values = new Map(Object.entries(initial));
    this.listeners = new Map();
  }
  get(key) {
    return this.values.get(key);
  }
  async set(key, value) {
    this.values.set(key, value);
    for (const listener of this.listeners.get(key) ?? []) {
      listener(value);
    }
  }
  addChangeListener(key, listener) {
    if (!this.listeners.has(key)) {
      this.listeners.set(key, new Set());
    }
    this.listeners.get(key).add(listener);
  }
  removeChangeListener(key, listener) {
    this.listeners.get(key)?.delete(listener);
  }
}

// Studio keeps its sidebars' state in localStorage ("fox.workspace"); on a browser's first visit, start
// with the data source sidebar closed so that the layout has the whole window (1600 px wide fits it)
function closeSidebarOnFirstVisit() {
  const key = "fox.workspace";
  if (window.localStorage.getItem(key) == undefined) {
    window.localStorage.setItem(key, JSON.stringify({ state: { sidebarItem: null, leftSidebarOpen: false },
                                                      version: 0 }));
  }
}

// Studio keeps showing the last data it received when the monitor goes away, which looks alive: while the
// monitor's WebSocket (the URL's ds.url) cannot be reached, a red bar across the top says so, with the time it
// was lost. A second connection of its own, which subscribes to nothing, watches it and retries every second.
const CONNECTION_BANNER_ID = "connection-lost";
function watchConnection() {
  const params = new URLSearchParams(window.location.search);
  const url = params.get("ds.url");
  if (params.get("ds") !== "foxglove-websocket" || !url) {
    return;
  }
  const banner = document.createElement("div");
  banner.id = CONNECTION_BANNER_ID;
  banner.setAttribute("role", "alert");
  banner.style.cssText = "position: fixed; top: 0; left: 0; right: 0; z-index: 100000; padding: 4px 12px; " +
    "background: #b71c1c; color: #fff; font: 600 14px sans-serif; text-align: center; display: none";
  document.body.appendChild(banner);
  let lostAt;
  const connect = () => {
    const socket = new WebSocket(url, ["foxglove.sdk.v1", "foxglove.websocket.v1"]);
    socket.onopen = () => {
      lostAt = undefined;
      banner.style.display = "none";
    };
    socket.onclose = () => {
      lostAt = lostAt ?? new Date();
      banner.textContent = `No connection to the monitor (${url}) since ${lostAt.toLocaleTimeString()}: ` +
        "every panel shows old data. Reconnecting...";
      banner.style.display = "block";
      setTimeout(connect, 1000);
    };
  };
  connect();
}

async function start() {
  const root = document.getElementById("root");
  closeSidebarOnFirstVisit();
  watchConnection();
  const response = await fetch("layout.json");
  if (!response.ok) {
    throw new Error(`layout.json: HTTP ${response.status}`);
  }
  const data = await response.json();
  const now = new Date().toISOString();
  const layout = {
    id: LAYOUT_ID,
    name: LAYOUT_NAME,
    permission: "CREATOR_WRITE",
    baseline: { data, savedAt: now },
    working: undefined,
    syncInfo: undefined,
  };
  await initI18n();
  await waitForFonts();
  const props = {
    deepLinks: [window.location.href],
    // no telemetry, no crash reports, and no "open data source" dialog at start-up (its links are online-only;
    // the URL names the data source)
    appConfiguration: new MemoryAppConfiguration({ [AppSetting.TELEMETRY_ENABLED]: false,
                                                   [AppSetting.CRASH_REPORTING_ENABLED]: false,
                                                   [AppSetting.SHOW_OPEN_DIALOG_ON_STARTUP]: false }),
    dataSources: [new FoxgloveWebSocketDataSourceFactory(), new McapLocalDataSourceFactory(),
                  new RemoteDataSourceFactory()],
    layoutStorage: new MemoryLayoutStorage([layout]),
    extensionLoaders: [],
    enableLaunchPreferenceScreen: false,
    enableGlobalCss: true,
  };
  ReactDOM.render(React.createElement(App, props), root);
  console.debug("viewer rendered");
}

start().catch((error) => {
  console.error(error);
  document.getElementById("root").textContent = `The viewer failed to start: ${error}`;
});
