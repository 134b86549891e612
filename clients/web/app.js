// rim dashboard: follows every mapping session of a rim_server through its read-only JSON API
// (rim_server --http) and shows their mesh tiles, trajectories and numbers.
//
// Once a second it lists the sessions, then asks each session for the tiles whose version moved
// since the newest it has seen, and for the trajectory points after the last one it has. Tile
// bytes (Draco) are fetched, at most MAX_TILE_FETCHES at a time, only for tiles whose version
// moved, and decoded in DRACOLoader's workers.
//
// Tiles come in levels of detail (each session's `mesh_levels_m`); the page shows one level, by
// default the one nearest DEFAULT_LEVEL_M, or the one nearest `?resolution_m=R` in the URL, and
// the level select switches it (every session's tiles are dropped and listed again from since=0).
//
// The state is published as window.rimDashboard for tests and benchmarks (see publish()).
// A token given as #token=... in the URL is sent as `Authorization: Bearer ...`.
import { DRACOLoader } from 'three/addons/loaders/DRACOLoader.js';
import { DEFAULT_LEVEL_M, levelValue, nearestLevel, urlLevel } from './levels.js';
import { Panel } from './panel.js';
import { Viewer } from './viewer.js';

const API = '/api/v1/sessions';
const POLL_INTERVAL_MS = 1000;
const MAX_TILE_FETCHES = 4;
const API_TIMEOUT_MS = 15000;
const TILE_TIMEOUT_MS = 60000;
const MAX_ERRORS = 200;  // distinct messages kept; repeats are counted
// A poll that got no answer (timeout, network) is retried at the next round; only this many in a
// row for the same request count as an error (a busy server answers late, a dead one never).
const MAX_QUIET_RETRIES = 5;
const AUTO_FIT_MS = 250; // while the first tiles load, the view is refit at most this often
const DECODER_DIR = new URL('vendor/three/addons/libs/draco/', document.baseURI).href;

// A failed request: status is the HTTP status, or 0 when none came (network error, timeout).
class FetchError extends Error {
  constructor(status, message) {
    super(message);
    this.status = status;
  }
}

// One session as the dashboard follows it.
class SessionModel {
  constructor(robot) {
    this.robot = robot;
    this.entry = null;        // the latest entry from the sessions list
    this.tiles = new Map();   // "kx,ky,kz" -> TileModel
    this.since = 0;           // newest tile version listed so far
    this.mapVersion = 0;
    this.trajectoryNext = 0;  // index of the next trajectory point to ask for
    this.trajectoryPoints = 0;
    this.removed = false;     // gone from the list (or restarted): late results are dropped
    this.deferred = [];       // 404 errors, recorded only if the session is still listed
    this.levels = [];         // its levels of detail (metres), finest first, as the entry lists
    this.level = null;        // the level its tiles are listed at; null: none listed (the finest)
    this.generation = 0;      // bumped when its tiles are dropped: late listings are ignored
  }
}

// One tile of a session: the newest listed version, and what is shown.
class TileModel {
  constructor(session, key) {
    this.session = session;
    this.key = key;
    this.label = `${session.robot} tile [${key.join(', ')}]`;
    this.version = -1;       // newest listed version
    this.url = '';
    this.shownVersion = -1;  // version on screen (an empty tile shows nothing but counts)
    this.failedVersion = -1; // version whose fetch or decode failed; retried when it moves
    this.faces = 0;
    this.vertices = 0;
    this.queued = false;
    this.busy = false;
    this.dropped = false;    // its session switched level: late bytes are not shown
  }

  get wanted() {
    return !this.session.removed && !this.dropped && this.shownVersion < this.version
      && this.failedVersion < this.version;
  }
}

const state = {
  errors: [],            // distinct messages, oldest first
  errorCounts: new Map(),
  retriedPolls: 0,       // polls that got no answer and were retried quietly
  quietFailures: new Map(),  // request kind -> failures in a row
  polls: 0,              // completed poll rounds
  okPolls: 0,            // rounds whose sessions list came back
  serverVersion: null,
  token: null,
  // The level asked for (metres; 0: the finest): the URL's resolution_m, DEFAULT_LEVEL_M, or the
  // user's choice in the level select. The page shows the offered level nearest it (state.level).
  wantLevel: urlLevel() ?? DEFAULT_LEVEL_M,
  levels: [],            // every level some session offers, finest first
  level: null,           // the level shown: nearest wantLevel among `levels`
  levelSwitches: 0,      // times the shown level changed after the first
};
const sessions = new Map();  // robot id -> SessionModel, in the server's order
const tileQueue = [];
let tileFetches = 0;
let autoFit = true;          // until the first tiles are all in, or the user moves the view
let lastFitAt = -Infinity;
let panelDirty = true;

const panel = new Panel(document);
let viewer = null;
try {
  viewer = new Viewer(document.getElementById('view'));
} catch (e) {
  recordError(`3D view unavailable (WebGL): ${e.message}`);
}
const draco = new DRACOLoader();
draco.setDecoderPath({ js: `${DECODER_DIR}draco_wasm_wrapper.js`, wasm: `${DECODER_DIR}draco_decoder.wasm` });
draco.setWorkerLimit(Math.max(1, Math.min(MAX_TILE_FETCHES, navigator.hardwareConcurrency || 2)));

function readToken() {
  state.token = new URLSearchParams(location.hash.slice(1)).get('token') || null;
}

// ---- Errors and published state ----------------------------------------------------------------

function recordError(message) {
  const seen = state.errorCounts.get(message);
  if (seen !== undefined) {
    state.errorCounts.set(message, seen + 1);
  } else if (state.errors.length < MAX_ERRORS) {
    state.errors.push(message);
    state.errorCounts.set(message, 1);
    console.error(`rim dashboard: ${message}`);
  }
  panelDirty = true;
}

// A poll request failed. No answer at all (status 0: timeout or network) is retried at the next
// round without an error, unless it keeps happening; an answer that is an error is recorded.
function pollFailed(kind, text, error, onError) {
  if (error.status === 0) {
    const inRow = (state.quietFailures.get(kind) || 0) + 1;
    state.quietFailures.set(kind, inRow);
    state.retriedPolls++;
    console.warn(`rim dashboard: ${text} (retrying)`);
    if (inRow < MAX_QUIET_RETRIES) return;
  }
  onError(text);
}

function pollSucceeded(kind) {
  state.quietFailures.delete(kind);
}

function status() {
  if (state.errors.length > 0) return 'error';
  return state.okPolls > 0 ? 'ok' : 'starting';
}

// Per-session counts, from the tiles' states.
function sessionView(s) {
  const v = {
    entry: s.entry, mapVersion: s.mapVersion, tilesListed: s.tiles.size, level: s.level,
    tilesLoaded: 0, pending: 0, failed: 0, faces: 0, vertices: 0,
  };
  for (const t of s.tiles.values()) {
    if (t.shownVersion >= 0) {
      v.faces += t.faces;
      v.vertices += t.vertices;
    }
    if (t.shownVersion >= t.version) v.tilesLoaded++;
    else if (t.failedVersion >= t.version) v.failed++;
    else v.pending++;
  }
  return v;
}

// window.rimDashboard: { status, errors, polls, retried_polls, resolution_m, mesh_levels_m,
// level_switches, sessions: { ROBOT: { tiles_loaded, faces, vertices, pending, failed,
// map_version, trajectory_points, resolution_m } }, frame_ms: { median, p95 }, heap_bytes,
// color_mode, server_version, gpu: { renderer, antialias, geometries, draw_calls, triangles (the
// last frame's) } }. resolution_m: the level shown (null until a session lists its levels); a
// session's own resolution_m is the level its tiles are listed at (its level nearest the page's).
// Replaced (not mutated) on every poll and tile load.
function publish() {
  const out = {};
  for (const s of sessions.values()) {
    const v = sessionView(s);
    out[s.robot] = {
      tiles_loaded: v.tilesLoaded, faces: v.faces, vertices: v.vertices, pending: v.pending,
      failed: v.failed, map_version: s.mapVersion, trajectory_points: s.trajectoryPoints,
      resolution_m: s.level,
    };
  }
  window.rimDashboard = {
    status: status(),
    errors: state.errors.slice(),
    polls: state.polls,
    retried_polls: state.retriedPolls,
    resolution_m: state.level,
    mesh_levels_m: state.levels.slice(),
    level_switches: state.levelSwitches,
    sessions: out,
    frame_ms: viewer ? viewer.frameStats() : { median: null, p95: null },
    heap_bytes: performance.memory ? performance.memory.usedJSHeapSize : null,
    color_mode: document.getElementById('color-mode').value,
    server_version: state.serverVersion,
    gpu: viewer ? viewer.gpuStats() : null,
  };
  // The status and the error list change with the published state, in the same task, so that
  // whoever sees an error in window.rimDashboard finds it on the page too.
  panel.setStatus(window.rimDashboard.status);
  panel.showErrors(state.errors, state.errorCounts);
  panelDirty = true;
}

function updatePanel() {
  panelDirty = false;
  panel.setServerVersion(state.serverVersion);
  const views = new Map();
  let tiles = 0;
  let faces = 0;
  for (const s of sessions.values()) {
    if (!s.entry) continue;
    const v = sessionView(s);
    views.set(s.robot, v);
    tiles += v.tilesLoaded;
    faces += v.faces;
  }
  panel.showSessions(views);
  const frame = viewer ? viewer.frameStats() : null;
  const memory = performance.memory ? ` · heap ${(performance.memory.usedJSHeapSize / 1e6).toFixed(0)} MB` : '';
  panel.setTotals(`${views.size} sessions · ${tiles} tiles · ${faces.toLocaleString('en-US')} triangles`
    + (frame && frame.median !== null ? ` · frame ${frame.median.toFixed(1)} ms` : '') + memory);
}

// ---- Requests ----------------------------------------------------------------------------------

async function apiFetch(url, timeoutMs) {
  const headers = state.token ? { Authorization: `Bearer ${state.token}` } : {};
  let response;
  try {
    response = await fetch(url, { headers, cache: 'no-store', signal: AbortSignal.timeout(timeoutMs) });
  } catch (e) {
    throw new FetchError(0, e.name === 'TimeoutError'
      ? `no answer within ${timeoutMs / 1000} s` : `network error (${e.message})`);
  }
  if (!response.ok) {
    let detail = '';
    try {
      detail = (await response.json())?.error?.message ?? '';
    } catch {
      // Not the API's JSON error: the status says enough.
    }
    throw new FetchError(response.status,
      `HTTP ${response.status}${response.statusText ? ` ${response.statusText}` : ''}`
      + (detail ? `: ${detail}` : ''));
  }
  return response;
}

async function apiJson(url) {
  const response = await apiFetch(url, API_TIMEOUT_MS);
  try {
    return await response.json();
  } catch (e) {
    throw new FetchError(response.status, `unreadable answer (${e.message})`);
  }
}

// A failed request about one session. A 404 may only mean that the session closed since the
// list was fetched: it is kept until the next list shows whether the session is still there.
// `kind` names a poll (retried quietly when unanswered: pollFailed), or is null for a tile.
function sessionError(s, kind, message, error) {
  const text = `${message}: ${error.message}`;
  if (error.status === 404) s.deferred.push(text);
  else if (kind === null) recordError(text);  // a tile that cannot be fetched: always shown
  else pollFailed(`${kind} ${s.robot}`, text, error, recordError);
  noteAccess(error);
}

// Shows or clears the token banner after a request.
function noteAccess(error) {
  if (error && (error.status === 401 || error.status === 403)) {
    panel.setAuthProblem(error.status, state.token !== null);
  }
}

// ---- Polling -----------------------------------------------------------------------------------

let pollTimer = null;
let polling = false;

async function pollLoop() {
  pollTimer = null;
  polling = true;
  const started = performance.now();
  try {
    await pollRound();
  } catch (e) {
    recordError(`poll failed: ${e.message}`);  // a bug, not a failed request
    console.error(e);
  }
  polling = false;
  state.polls++;
  publish();
  pollTimer = setTimeout(pollLoop, Math.max(0, POLL_INTERVAL_MS - (performance.now() - started)));
}

// Starts the next round now, unless one is under way (then the one after it comes as usual).
function pollNow() {
  if (polling || pollTimer === null) return;
  clearTimeout(pollTimer);
  pollLoop();
}

async function pollRound() {
  let list;
  try {
    list = await apiJson(API);
  } catch (e) {
    pollFailed('sessions', `sessions list: ${e.message}`, e, recordError);
    noteAccess(e);
    return;
  }
  pollSucceeded('sessions');
  panel.setAuthProblem(null);
  state.okPolls++;
  state.serverVersion = list.server_version ?? null;
  reconcile(list.sessions || []);
  await Promise.all([...sessions.values()].map((s) => Promise.all([pollTiles(s), pollTrajectory(s)])));
}

// Follows the sessions list: new sessions are added, missing ones dropped with what they show.
function reconcile(entries) {
  const listed = new Map(entries.map((e) => [e.robot_id, e]));
  for (const s of sessions.values()) {
    const entry = listed.get(s.robot);
    // A session that went away, or one that was closed and opened again under the same robot id
    // between two polls (its counters went back), is dropped; a new one is followed from scratch.
    if (!entry || entry.map_version < s.mapVersion || entry.trajectory_length < s.trajectoryNext) {
      dropSession(s);
    }
  }
  const ordered = new Map();
  for (const [robot, entry] of listed) {
    const s = sessions.get(robot) || new SessionModel(robot);
    for (const message of s.deferred) recordError(message);
    s.deferred = [];
    s.entry = entry;
    s.mapVersion = Math.max(s.mapVersion, entry.map_version);
    viewer?.setPose(robot, entry.pose);
    ordered.set(robot, s);
  }
  sessions.clear();
  for (const [robot, s] of ordered) sessions.set(robot, s);
  for (const s of sessions.values()) {
    s.levels = (s.entry.mesh_levels_m || []).map(levelValue).filter((l) => l > 0);
  }
  applyLevel();
}

// Picks the level shown from what the sessions offer and state.wantLevel, and moves every
// session whose level changes to it: its tiles are dropped and listed again from since=0.
function applyLevel() {
  const offered = new Set();
  for (const s of sessions.values()) for (const l of s.levels) offered.add(l);
  state.levels = [...offered].sort((a, b) => a - b);
  const level = nearestLevel(state.levels, state.wantLevel);
  if (level !== state.level && state.level !== null && level !== null) state.levelSwitches++;
  state.level = level;
  panel.setLevels(state.levels, state.level);
  for (const s of sessions.values()) {
    // A session that lacks the page's level shows its own nearest one.
    const own = s.levels.includes(state.level) ? state.level : nearestLevel(s.levels, state.level);
    if (own !== s.level) setSessionLevel(s, own);
  }
}

function setSessionLevel(s, level) {
  s.level = level;
  s.generation++;
  for (const t of s.tiles.values()) t.dropped = true;
  s.tiles = new Map();
  s.since = 0;
  viewer?.clearTiles(s.robot);
  panelDirty = true;
}

// The user picked a level (metres) in the select: shown at once, listed at the next poll.
function chooseLevel(value) {
  if (!(value >= 0)) return;
  state.wantLevel = value;
  // The URL names the level, so that the page can be linked to as it is now (the #token stays).
  const params = new URLSearchParams(location.search);
  params.set('resolution_m', String(value));
  history.replaceState(null, '', `${location.pathname}?${params}${location.hash}`);
  applyLevel();
  publish();
  pollNow();
}

function dropSession(s) {
  s.removed = true;
  sessions.delete(s.robot);
  viewer?.removeSession(s.robot);
}

async function pollTiles(s) {
  const generation = s.generation;
  const level = s.level === null ? '' : `&resolution_m=${s.level}`;
  let body;
  try {
    body = await apiJson(`${API}/${encodeURIComponent(s.robot)}/tiles?since=${s.since}${level}`);
  } catch (e) {
    if (generation !== s.generation) return;  // asked for a level no longer shown
    sessionError(s, 'tiles', `${s.robot}: tile list since version ${s.since}`
      + (s.level === null ? '' : ` at ${s.level} m`), e);
    return;
  }
  pollSucceeded(`tiles ${s.robot}`);
  if (s.removed || generation !== s.generation) return;
  s.mapVersion = Math.max(s.mapVersion, body.map_version || 0);
  for (const info of body.tiles || []) {
    const id = info.key.join(',');
    let t = s.tiles.get(id);
    if (!t) {
      t = new TileModel(s, info.key);
      s.tiles.set(id, t);
    }
    if (info.version > t.version) {
      t.version = info.version;
      t.url = info.url;
    }
    s.since = Math.max(s.since, info.version);
    if (t.wanted) enqueueTile(t);
  }
  // A listing cut short by the server's time budget lists every tile up to `next_since` and
  // perhaps some of the next version: go on from `next_since`, so none is skipped.
  if (typeof body.next_since === 'number') s.since = body.next_since;
  pumpTiles();
}

async function pollTrajectory(s) {
  let body;
  try {
    body = await apiJson(`${API}/${encodeURIComponent(s.robot)}/trajectory?since=${s.trajectoryNext}`);
  } catch (e) {
    sessionError(s, 'trajectory', `${s.robot}: trajectory since frame ${s.trajectoryNext}`, e);
    return;
  }
  pollSucceeded(`trajectory ${s.robot}`);
  if (s.removed) return;
  const positions = body.positions || [];
  viewer?.appendTrajectory(s.robot, positions);
  s.trajectoryPoints += positions.length;
  s.trajectoryNext = Math.max(s.trajectoryNext, body.next || 0);
}

// ---- Tiles -------------------------------------------------------------------------------------

function enqueueTile(t) {
  if (t.queued || t.busy) return;
  t.queued = true;
  tileQueue.push(t);
}

function pumpTiles() {
  while (tileFetches < MAX_TILE_FETCHES && tileQueue.length > 0) {
    const t = tileQueue.shift();
    t.queued = false;
    if (!t.wanted) continue;
    tileFetches++;
    t.busy = true;
    loadTile(t).catch((e) => {
      t.failedVersion = t.version;  // a bug, not a failed request: do not retry it in a loop
      recordError(`${t.label} v${t.version}: ${e.message}`);
      console.error(e);
    }).finally(() => {
      tileFetches--;
      t.busy = false;
      if (t.wanted) enqueueTile(t);  // its version moved while it loaded
      publish();
      maybeFit();
      pumpTiles();
    });
  }
}

// Decodes Draco bytes (the buffer is handed over to a worker). DRACOLoader rejects with the
// worker's message ({ error: text }) or an Error; either becomes an Error.
function decodeDraco(buffer) {
  return new Promise((resolve, reject) => draco.parse(buffer, resolve, (e) => {
    reject(e instanceof Error ? e : new Error(e?.error || String(e)));
  }));
}

async function loadTile(t) {
  const s = t.session;
  const version = t.version;
  const what = `${t.label} v${version}`;
  let bytes;
  let bytesVersion = version;
  try {
    const response = await apiFetch(t.url, TILE_TIMEOUT_MS);
    // The server sends the tile as it is now, which may be newer than the listed version.
    bytesVersion = Math.max(version, Number(response.headers.get('X-Rim-Tile-Version')) || 0);
    bytes = await response.arrayBuffer();
  } catch (e) {
    if (s.removed || t.dropped) return;
    t.failedVersion = version;
    if (e instanceof FetchError) sessionError(s, null, what, e);
    else recordError(`${what}: ${e.message}`);  // the body was cut off
    return;
  }
  if (s.removed || t.dropped) return;

  let geometry = null;  // an empty tile (no faces) has an empty body and shows nothing
  if (bytes.byteLength > 0) {
    try {
      geometry = await decodeDraco(bytes);
      if (!geometry.attributes.position) throw new Error('no positions');
    } catch (e) {
      if (t.dropped) return;
      t.failedVersion = version;
      recordError(`${what}: decode failed (${e.message})`);
      return;
    }
    if (s.removed || t.dropped || bytesVersion <= t.shownVersion) {
      geometry.dispose();
      return;
    }
  }
  t.vertices = geometry ? geometry.attributes.position.count : 0;
  t.faces = geometry ? Math.floor((geometry.index ? geometry.index.count : t.vertices) / 3) : 0;
  t.shownVersion = bytesVersion;
  t.version = Math.max(t.version, bytesVersion);
  viewer?.setTile(s.robot, t.key.join(','), geometry);
}

// While the first tiles come in, keeps the view fitted to them (until the user moves it, or
// until no tile is pending any more).
function maybeFit() {
  if (!autoFit || !viewer) return;
  if (viewer.userMoved) {
    autoFit = false;
    return;
  }
  const now = performance.now();
  let pending = false;
  for (const s of sessions.values()) {
    for (const t of s.tiles.values()) {
      if (t.wanted) {
        pending = true;
        break;
      }
    }
    if (pending) break;
  }
  if (!pending || now - lastFitAt >= AUTO_FIT_MS) {
    if (viewer.fit()) {
      lastFitAt = now;
      if (!pending) autoFit = false;
    }
  }
}

// ---- Page --------------------------------------------------------------------------------------

function refreshPanel() {
  if (panelDirty) updatePanel();
  requestAnimationFrame(refreshPanel);
}

readToken();
window.addEventListener('hashchange', readToken);
const colorMode = document.getElementById('color-mode');
colorMode.addEventListener('change', () => {
  viewer?.setColorMode(colorMode.value);
  publish();
});
viewer?.setColorMode(colorMode.value);  // the browser may restore a previous choice
document.getElementById('show-trajectories').addEventListener('change', (e) => {
  viewer?.setTrajectoriesVisible(e.target.checked);
});
document.getElementById('fit').addEventListener('click', () => {
  autoFit = false;
  viewer?.fit();
});
const levelSelect = document.getElementById('level');
levelSelect.addEventListener('change', () => chooseLevel(Number(levelSelect.value)));

publish();
requestAnimationFrame(refreshPanel);
pollLoop();
