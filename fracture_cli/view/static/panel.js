// The side panel's text: the bake report (recipe, counts, checks, seconds) and the last hit.

function escape(text) {
  return String(text).replace(/[&<>"']/g, (c) => ({ '&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;', "'": '&#39;' })[c]);
}

export function formatNumber(value) {
  if (typeof value !== 'number') return escape(JSON.stringify(value));
  if (Number.isInteger(value)) return String(value);
  if (value === 0) return '0';
  const magnitude = Math.abs(value);
  return magnitude >= 1e-3 && magnitude < 1e5 ? value.toPrecision(4).replace(/\.?0+$/, '') : value.toExponential(2);
}

function cell(value) {
  if (value === true) return '<span class="ok">true</span>';
  if (value === false) return '<span class="bad">false</span>';
  if (Array.isArray(value)) return escape(value.map(formatNumber).join(' '));
  if (typeof value === 'string') return escape(value);
  return formatNumber(value);
}

function table(title, entries) {
  const rows = entries.map(([key, value]) => `<tr><td>${escape(key)}</td><td>${cell(value)}</td></tr>`).join('');
  return `<div class="sub">${escape(title)}</div><table>${rows}</table>`;
}

/** HTML for the "Bake" section: the runtime file's numbers and, when present, the report's. */
export function reportHtml(stem, runtime, report) {
  const parts = [];
  const runtimeRows = [
    ['fragments', runtime.numFragments], ['modes (k)', runtime.numModes], ['dim (d)', runtime.dim],
    ['bonds', runtime.numEdges], ['contact sites', runtime.numSites],
    ['default threshold', runtime.defaultThreshold], ['impact radius', runtime.impactRadius],
  ];
  if (runtime.features.length) runtimeRows.push(['features', runtime.features.join(' ')]);
  if (runtime.anchored) runtimeRows.push(['anchored fragments', runtime.anchored.reduce((n, a) => n + a, 0)]);
  if (runtime.damage) runtimeRows.push(['crack level', runtime.damage.crackLevel], ['damage rate', runtime.damage.damageRate]);
  if (runtime.crackSegments) runtimeRows.push(['crack segments', runtime.crackSegments.length / 6]);
  if (!report) {
    parts.push(`<div>${escape(stem)}: no ${escape(stem)}.report.json next to the runtime file</div>`);
    parts.push(table('runtime file', runtimeRows));
    return parts.join('');
  }
  const recipe = report.recipe || {};
  const chain = (recipe.chain || []).length > 1 ? ` (extends ${recipe.chain.slice(1).join(' → ')})` : '';
  parts.push(`<div><b>${escape((report.input || {}).name || stem)}</b> · recipe <b>${escape(recipe.name || '?')}</b>${escape(chain)}</div>`);
  if (recipe.description) parts.push(`<div class="sub">${escape(recipe.description)}</div>`);
  const input = report.input || {};
  parts.push(table('input', [['triangles', input.triangles], ['vertices', input.vertices]].filter(([, v]) => v !== undefined)));
  parts.push(table('counts', Object.entries(report.counts || {})));
  parts.push(table('runtime file', runtimeRows.slice(5)));
  parts.push(table('checks', Object.entries(report.checks || {})));
  const seconds = Object.entries(report.seconds || {});
  const total = seconds.reduce((sum, [, v]) => sum + (typeof v === 'number' ? v : 0), 0);
  parts.push(table('seconds', [...seconds, ['total', Math.round(total * 1000) / 1000]]));
  parts.push(`<div class="sub">fracture ${escape(report.version || '?')}</div>`);
  return parts.join('');
}

/** The weakest bond that holds: {bond, health}, or null when every bond is broken. */
export function weakestBond(hit) {
  let weakest = null;
  hit.health.forEach((h, m) => {
    if (!hit.broken[m] && (weakest === null || h < weakest.health)) weakest = { bond: m, health: h };
  });
  return weakest;
}

/** HTML for a structure's state after a hit: cracked bonds, the lowest health, what stays and what falls. */
function structureHtml(hit, runtime) {
  const cracked = hit.cracked.filter(Boolean).length;
  const weakest = weakestBond(hit);
  const lowest = weakest ? `lowest health <b id="lowest-health">${formatNumber(weakest.health)}</b> (bond ${weakest.bond})` : 'every bond broken';
  const parts = [`<div><b>${cracked}</b> bond${cracked === 1 ? '' : 's'} cracked · ${lowest}</div>`];
  if (runtime.anchored) {
    const groups = new Set(hit.groups);
    const held = new Set(hit.groups.filter((g, j) => hit.anchored[j] === 1));
    const still = hit.anchored.filter((a) => a === 1).length;
    parts.push(`<div class="sub">held by the world: ${still} fragment${still === 1 ? '' : 's'} in ${held.size} group${held.size === 1 ? '' : 's'} (stay still) · ${groups.size - held.size} group${groups.size - held.size === 1 ? '' : 's'} fall</div>`);
  }
  return parts.join('');
}

/** HTML for the last hit: groups with their fragment names, broken bonds, site (and a structure's damage). */
export function hitHtml(hit, fragmentNames, runtime) {
  const members = new Map();
  hit.groups.forEach((g, j) => {
    if (!members.has(g)) members.set(g, []);
    members.get(g).push(fragmentNames[j]);
  });
  const brokenCount = hit.broken.filter(Boolean).length;
  const lines = [...members.entries()].map(([g, names]) => `<tr><td>group_${String(g).padStart(3, '0')}</td><td>${escape(names.length)} fragment${names.length > 1 ? 's' : ''}</td></tr>`);
  const structure = runtime.anchored || runtime.damage ? structureHtml(hit, runtime) : '';
  return `<div><b>${hit.numGroups}</b> group(s), <b>${brokenCount}</b> of ${hit.broken.length} bonds broken</div>${structure}`
    + `<div class="sub">point ${hit.point.map(formatNumber).join(' ')} · |impulse| ${formatNumber(Math.hypot(...hit.impulse))} · threshold ${formatNumber(hit.threshold)} · site ${hit.site}</div>`
    + `<table>${lines.join('')}</table>`;
}
