// The side panel: status, the access-token banner, the error list and one card per session.
// Cards are built once per session and then only their text changes.
import { robotCss } from './viewer.js';

const integer = new Intl.NumberFormat('en-US');
const fixed1 = new Intl.NumberFormat('en-US', { minimumFractionDigits: 1, maximumFractionDigits: 1 });
const plural = (n, word) => `${integer.format(n)} ${word}${n === 1 ? '' : 's'}`;
const metres = (level) => `${level} m`;

// Rows of a session card: label, and the text for a session's view model.
const ROWS = [
  ['Accepted / integrated', (v) => `${integer.format(v.entry.accepted_frames)} / ${integer.format(v.entry.integrated_frames)}`
    + (v.entry.rejected_frames ? ` (${integer.format(v.entry.rejected_frames)} rejected)` : '')],
  ['Lag', (v) => `${plural(v.entry.lag_frames, 'frame')}, queue ${integer.format(v.entry.queue_depth)}`],
  ['Iterations/frame', (v) => integer.format(v.entry.iterations_per_frame)],
  ['Map version', (v) => integer.format(v.mapVersion)],
  ['Memory', (v) => `${fixed1.format(v.entry.host_memory_bytes / 1e6)} MB`],
  ['Sub-maps active', (v) => integer.format(v.entry.submaps_active)],
  ['Tiles loaded', (v) => `${integer.format(v.tilesLoaded)} / ${integer.format(v.tilesListed)}`
    + (v.pending ? `, ${integer.format(v.pending)} pending` : '')
    + (v.failed ? `, ${integer.format(v.failed)} failed` : '')],
  ['Triangles', (v) => integer.format(v.faces)],
  ['Mesh level', (v) => (v.level === null ? 'finest' : metres(v.level))],
  ['Last loss', (v) => (Number.isFinite(v.entry.last_loss) ? v.entry.last_loss.toPrecision(3) : '–')],
  ['Position', (v) => (v.entry.pose
    ? `${v.entry.pose.position.map((c) => c.toFixed(1)).join(', ')} m`
    : 'no frame yet')],
];
const LAG_ROW = 1;

export class Panel {
  constructor(doc) {
    this.doc = doc;
    this.status = doc.getElementById('status');
    this.serverVersion = doc.getElementById('server-version');
    this.auth = doc.getElementById('auth');
    this.errors = doc.getElementById('errors');
    this.errorList = doc.getElementById('error-list');
    this.sessionList = doc.getElementById('sessions');
    this.noSessions = doc.getElementById('no-sessions');
    this.totals = doc.getElementById('totals');
    this.level = doc.getElementById('level');
    this.levelOptions = '';  // the levels the select lists, to rebuild it only when they change
    this.cards = new Map();  // robot id -> { root, preset, frozen, values: [dd...] }
    this.order = '';         // robot ids as listed, to re-order cards only when that changes
    this.shownErrors = 0;
  }

  setStatus(status) {
    if (this.status.textContent === status) return;
    this.status.textContent = status;
    this.status.className = `pill ${status}`;
  }

  setServerVersion(version) {
    this.serverVersion.textContent = version ? `server ${version}` : '';
  }

  // An access problem (HTTP 401 or 403), or null to clear it.
  setAuthProblem(status, hasToken) {
    if (!status) {
      this.auth.hidden = true;
      return;
    }
    let html;
    if (status === 401 && !hasToken) {
      html = 'This server needs an access token. Open the dashboard as '
        + '<code>…/#token=YOUR_TOKEN</code> (a token of a role that may read sessions).';
    } else if (status === 401) {
      html = 'The server refused the token in the URL (<code>#token=…</code>): check it, '
        + 'then fix the URL.';
    } else {
      html = 'The token in the URL (<code>#token=…</code>) is valid, but its role may not read '
        + 'sessions: use a viewer or operator token.';
    }
    this.auth.innerHTML = html;
    this.auth.hidden = false;
  }

  // errors: unique messages in order; counts: message -> times seen. Appends what is new.
  showErrors(errors, counts) {
    for (; this.shownErrors < errors.length; this.shownErrors++) {
      const li = this.doc.createElement('li');
      li.append(this.doc.createTextNode(errors[this.shownErrors]), this.doc.createElement('span'));
      li.lastChild.className = 'repeat';
      this.errorList.append(li);
    }
    errors.forEach((message, i) => {
      const n = counts.get(message) || 1;
      const repeat = this.errorList.children[i].lastChild;
      const text = n > 1 ? ` (×${n})` : '';
      if (repeat.textContent !== text) repeat.textContent = text;
    });
    this.errors.hidden = errors.length === 0;
  }

  // views: robot id -> view model { entry, mapVersion, tilesListed, level, tilesLoaded, pending,
  // failed, faces }, in the order the server lists the sessions.
  showSessions(views) {
    for (const [robot, card] of this.cards) {
      if (!views.has(robot)) {
        card.root.remove();
        this.cards.delete(robot);
      }
    }
    const order = [...views.keys()].join('\n');
    for (const [robot, view] of views) {
      let card = this.cards.get(robot);
      if (!card) {
        card = this._card(robot);
        this.cards.set(robot, card);
      }
      if (order !== this.order) this.sessionList.append(card.root);  // the server's order
      card.preset.textContent = view.entry.preset || '';
      card.preset.hidden = !view.entry.preset;
      card.frozen.hidden = !view.entry.decoder_frozen;
      ROWS.forEach(([, text], i) => {
        const value = text(view);
        if (card.values[i].textContent !== value) card.values[i].textContent = value;
      });
      card.values[LAG_ROW].classList.toggle('warn', view.entry.lag_frames > 0);
    }
    this.order = order;
    this.noSessions.hidden = views.size > 0;
  }

  // The level select: `levels` (metres, finest first) listed coarsest first, `level` selected.
  setLevels(levels, level) {
    const key = levels.join(',');
    if (key !== this.levelOptions) {
      this.levelOptions = key;
      const options = [...levels].reverse().map((l) => {
        const option = this.doc.createElement('option');
        option.value = String(l);
        option.textContent = metres(l);
        return option;
      });
      if (options.length === 0) {
        const none = this.doc.createElement('option');
        none.value = '';
        none.textContent = '–';
        options.push(none);
      }
      this.level.replaceChildren(...options);
      this.level.disabled = levels.length === 0;
    }
    const value = level === null ? '' : String(level);
    if (this.level.value !== value) this.level.value = value;
  }

  setTotals(text) {
    if (this.totals.textContent !== text) this.totals.textContent = text;
  }

  _card(robot) {
    const d = this.doc;
    const root = d.createElement('article');
    root.className = 'session';
    root.dataset.robot = robot;
    const title = d.createElement('h3');
    const swatch = d.createElement('span');
    swatch.className = 'swatch';
    swatch.style.background = robotCss(robot);
    const name = d.createElement('span');
    name.textContent = robot;
    const preset = d.createElement('span');
    preset.className = 'badge';
    const frozen = d.createElement('span');
    frozen.className = 'badge';
    frozen.textContent = 'decoder frozen';
    title.append(swatch, name, preset, frozen);
    const dl = d.createElement('dl');
    const values = ROWS.map(([label]) => {
      const dt = d.createElement('dt');
      dt.textContent = label;
      const dd = d.createElement('dd');
      dl.append(dt, dd);
      return dd;
    });
    root.append(title, dl);
    return { root, preset, frozen, values };
  }
}
