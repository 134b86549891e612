// Levels of detail of the dashboard's tiles (docs/dashboard.md): how the page names a level, which
// level of a session's it shows, and the level its URL asks for.

// The level of detail asked for by default (metres): the level nearest it that the sessions offer.
// A coarse level loads and draws several times faster than the finest (docs/service.md).
export const DEFAULT_LEVEL_M = 0.2;

// A level as the page names it: the server's float32 metres to the shortest decimal (0.2, not
// 0.20000000298023224), so that equal levels of different sessions compare equal.
export function levelValue(x) {
  return Number(Number(x).toPrecision(6));
}

// The level of `levels` nearest `want` (metres; 0: the finest); ties go to the finer one.
// null when there are none.
export function nearestLevel(levels, want) {
  if (levels.length === 0) return null;
  const sorted = [...levels].sort((a, b) => a - b);
  if (!(want > 0)) return sorted[0];
  let best = sorted[0];
  for (const l of sorted) if (Math.abs(l - want) < Math.abs(best - want)) best = l;
  return best;
}

// The `resolution_m` of the page's URL query (?resolution_m=0.05): a number >= 0, or null when
// absent or not one (then the default applies).
export function urlLevel() {
  const text = new URLSearchParams(location.search).get('resolution_m');
  if (text === null || text.trim() === '') return null;
  const value = Number(text);
  if (!Number.isFinite(value) || value < 0) {
    console.warn(`rim dashboard: ignoring resolution_m=${text} in the URL (not metres >= 0)`);
    return null;
  }
  return value;
}
