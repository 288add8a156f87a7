"use strict";
// The mission-control view (cikan_ros.view): the approach in the chief's LVLH frame (line-of-sight
// cone, docking port, paths, virtual target, deputy) and every telemetry point against its limits,
// from /data.json (cikan_ros.view.data.payload); a time slider moves the markers, the cone (its
// axis follows the chief's velocity) and a cursor on the plots. /version is polled while a
// followed mission flies.

const COLORS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22",
                "#7f7f7f", "#d62728"];
const LIMIT_COLOR = "#c62828";
const POLL_MS = 500;
// Points of a 2-D trace beyond which it is drawn with WebGL (scattergl).
const GL_POINTS = 20000;
// Least height of one plot row (px).
const ROW_PX = 110;

// The page's state; `ready`, `loadMs` (first draw done, ms since navigation) and `renderMs` (the
// last draw's parts) are read by the browser tests and the load measurement.
const view = {data: null, version: 0, index: 0, following: true, ready: false, loadMs: null, renderMs: null,
              markerTraces: [], targetTrace: null, groups: []};
window.cikanView = view;

const slider = document.getElementById("slider");

function fetchJSON(url) {
  return fetch(url, {cache: "no-store"}).then(r => {
    if (!r.ok) throw new Error(`${url}: HTTP ${r.status}`);
    return r.json();
  });
}

function groupsOf(runs) {
  const out = new Map();
  for (const r of runs) {
    if (!out.has(r.group)) out.set(r.group, []);
    out.get(r.group).push(r);
  }
  return out;
}

// The values of several runs in one array, the runs separated by null (one trace per group).
function joined(runs, get) {
  const out = [];
  runs.forEach((r, n) => {
    if (n) out.push(null);
    for (const v of get(r)) out.push(v);
  });
  return out;
}

// Index of the sample of times t (ascending) nearest to time s.
function nearest(t, s) {
  let lo = 0, hi = t.length - 1;
  while (hi - lo > 1) {
    const mid = (lo + hi) >> 1;
    if (t[mid] <= s) lo = mid; else hi = mid;
  }
  return Math.abs(t[hi] - s) < Math.abs(t[lo] - s) ? hi : lo;
}

function clock(s) {
  const h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60), sec = Math.round(s % 60);
  return `${h} h ${String(m).padStart(2, "0")} min ${String(sec).padStart(2, "0")} s`;
}

function cross(a, b) {
  return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
}

function unit(a) {
  const n = Math.hypot(a[0], a[1], a[2]);
  return [a[0] / n, a[1] / n, a[2] / n];
}

// The line-of-sight cone as a wireframe (its rim and GENERATORS lines from the apex; lines, as
// the paths: a mesh would cost the first draw another WebGL program, about 0.4 s in software GL):
// apex at the chief (the docking port), axis a (unit, LVLH), half angle and length from the scene.
const GENERATORS = 12;
function coneLines(scene, a) {
  const len = 1.1 * scene.reach_m, r = len * Math.tan(scene.half_angle_deg * Math.PI / 180), n = 48;
  const u = unit(cross(a, Math.abs(a[0]) < 0.9 ? [1, 0, 0] : [0, 1, 0])), v = cross(a, u);
  const rim = s => {
    const c = Math.cos(2 * Math.PI * s / n), sn = Math.sin(2 * Math.PI * s / n);
    return [0, 1, 2].map(i => a[i] * len + r * (c * u[i] + sn * v[i]));
  };
  const x = [], y = [], z = [];
  const add = p => { x.push(p === null ? null : p[0]); y.push(p === null ? null : p[1]); z.push(p === null ? null : p[2]); };
  for (let s = 0; s <= n; s++) add(rim(s % n));
  for (let g = 0; g < GENERATORS; g++) {
    add(null); add([0, 0, 0]); add(rim(g * n / GENERATORS));
  }
  return {x, y, z};
}

function axisAt(d, index) {
  const ax = d.runs[0].axis;
  return [ax[0][index], ax[1][index], ax[2][index]];
}

function sceneFigure(d) {
  const single = d.runs.length === 1;
  const traces = [];
  traces.push({type: "scatter3d", mode: "lines", name: `line-of-sight cone (${d.scene.half_angle_deg}°, ${d.side})`,
               ...coneLines(d.scene, axisAt(d, view.index)), connectgaps: false, hoverinfo: "skip",
               line: {color: "#4a90d9", width: 2}, opacity: 0.5});
  traces.push({type: "scatter3d", mode: "markers", name: "docking port (chief)", x: [0], y: [0], z: [0],
               marker: {symbol: "diamond", size: 5, color: "#1c2430"}});
  view.groups.forEach(([group, runs], n) => {
    traces.push({type: "scatter3d", mode: "lines", name: single ? `path (${group})` : group,
                 legendgroup: group, x: joined(runs, r => r.deputy[0]), y: joined(runs, r => r.deputy[1]),
                 z: joined(runs, r => r.deputy[2]), connectgaps: false, hoverinfo: single ? "x+y+z" : "name",
                 line: {color: COLORS[n % COLORS.length], width: single ? 4 : 2}, opacity: single ? 1 : 0.6});
  });
  if (single && d.runs[0].target) {
    const tg = d.runs[0].target;
    traces.push({type: "scatter3d", mode: "lines", name: "virtual target path", x: tg[0], y: tg[1], z: tg[2],
                 line: {color: "#2ca02c", width: 2}, connectgaps: false});
    view.targetTrace = traces.length;
    traces.push({type: "scatter3d", mode: "markers", name: "virtual target", x: [], y: [], z: [],
                 marker: {symbol: "circle-open", size: 6, color: "#2ca02c"}});
  } else {
    view.targetTrace = null;
  }
  view.markerTraces = [];
  view.groups.forEach(([group], n) => {
    view.markerTraces.push(traces.length);
    traces.push({type: "scatter3d", mode: "markers", name: single ? "deputy" : `deputy: ${group}`,
                 legendgroup: group, x: [], y: [], z: [], marker: {size: single ? 6 : 3,
                 color: single ? "#d62728" : COLORS[n % COLORS.length]}});
  });
  const [ax, ay, az] = d.axes;
  const layout = {
    uirevision: d.source, margin: {l: 0, r: 0, t: 30, b: 0},
    title: {text: "Approach in the chief's LVLH frame", font: {size: 13}},
    legend: {x: 0, y: 1, bgcolor: "rgba(255,255,255,0.7)"},
    scene: {aspectmode: "data", xaxis: {title: {text: ax}}, yaxis: {title: {text: ay}}, zaxis: {title: {text: az}}},
  };
  return {traces, layout};
}

function plotsFigure(d) {
  const points = d.telemetry;
  const rows = points.length, gap = 0.035, h = (1 - gap * (rows - 1)) / rows;
  const total = d.runs.reduce((s, r) => s + r.t.length, 0);
  const kind = total > GL_POINTS ? "scattergl" : "scatter";
  const tmax = Math.max(...d.runs.map(r => r.t[r.t.length - 1] / 3600));
  const traces = [], annotations = [];
  // each row keeps a readable height; the column scrolls when they do not fit
  const height = Math.max(document.getElementById("plots-box").clientHeight, ROW_PX * rows + 50);
  const layout = {uirevision: d.source, showlegend: false, margin: {l: 70, r: 20, t: 26, b: 40}, height,
                  hovermode: "closest", annotations,
                  xaxis: {title: {text: "mission time (h)"}, anchor: `y${rows}`, range: [0, tmax]},
                  shapes: [{type: "line", xref: "x", yref: "paper", x0: 0, x1: 0, y0: 0, y1: 1,
                            line: {color: "#5b6675", width: 1, dash: "dot"}}]};
  points.forEach((p, row) => {
    const yname = `y${row + 1}`, top = 1 - row * (h + gap);
    // a quantity with a docking bound (range, speed) spans decades down to it: log scale
    const log = p.goal_high !== null && p.goal_high !== undefined;
    layout[`yaxis${row + 1}`] = {domain: [top - h, top], anchor: "x", exponentformat: "e", type: log ? "log" : "linear"};
    annotations.push({text: `<b>${p.name}</b> (${p.unit})`, xref: "paper", yref: "paper", x: 0, y: top,
                      xanchor: "left", yanchor: "bottom", showarrow: false, font: {size: 12}});
    view.groups.forEach(([group, runs], n) => {
      const values = runs.filter(r => r.values[p.key]);
      if (!values.length) return;
      traces.push({type: kind, mode: "lines", name: group, xaxis: "x", yaxis: yname,
                   x: joined(values, r => r.t.map(s => s / 3600)), y: joined(values, r => r.values[p.key]),
                   connectgaps: false, line: {color: COLORS[n % COLORS.length], width: 1.5},
                   hovertemplate: `${group}<br>%{x:.3f} h<br>%{y:.4g} ${p.unit}<extra></extra>`});
    });
    for (const lim of [p.limit_low, p.limit_high]) {
      if (lim === null || lim === undefined) continue;
      traces.push({type: "scatter", mode: "lines", name: "limit", xaxis: "x", yaxis: yname, x: [0, tmax],
                   y: [lim, lim], line: {color: LIMIT_COLOR, width: 1, dash: "dash"}, hoverinfo: "skip"});
    }
    if (p.limit_key) {   // a limit that varies in time: another point's values
      traces.push({type: kind, mode: "lines", name: "limit", xaxis: "x", yaxis: yname,
                   x: joined(d.runs, r => r.t.map(s => s / 3600)), y: joined(d.runs, r => r.values[p.limit_key]),
                   connectgaps: false, line: {color: LIMIT_COLOR, width: 1, dash: "dash"},
                   hovertemplate: `limit<br>%{x:.3f} h<br>%{y:.4g} ${p.unit}<extra></extra>`});
    }
    if (p.goal_high !== null && p.goal_high !== undefined) {   // the docking test's bound
      traces.push({type: "scatter", mode: "lines", name: "docking test", xaxis: "x", yaxis: yname, x: [0, tmax],
                   y: [p.goal_high, p.goal_high], line: {color: "#2e7d32", width: 1, dash: "dot"},
                   hoverinfo: "skip"});
    }
    const bx = [], by = [];
    for (const r of d.runs) {
      for (const i of (r.violations[p.key] || [])) {
        bx.push(r.t[i] / 3600); by.push(r.values[p.key][i]);
      }
    }
    if (bx.length) {
      traces.push({type: kind, mode: "markers", name: "violation", xaxis: "x", yaxis: yname, x: bx, y: by,
                   marker: {symbol: "x", size: 7, color: LIMIT_COLOR},
                   hovertemplate: `violation of ${p.name}<br>%{x:.3f} h<br>%{y:.4g} ${p.unit}<extra></extra>`});
    }
  });
  return {traces, layout};
}

function status(d) {
  const el = document.getElementById("status");
  const bad = d.runs.reduce((s, r) => s + Object.values(r.violations).reduce((a, v) => a + v.length, 0), 0);
  const what = d.kind === "montecarlo" ? `${d.runs.length} runs (${view.groups.map(g => g[0]).join(", ")})`
                                        : d.runs[0].group;
  const live = d.kind === "live" ? (d.complete ? " · mission complete" : " · live, following the recorder") : "";
  el.textContent = `${what} · approach from ${d.side}${live} · ` +
                   (bad ? `${bad} samples beyond a limit` : "every sample within its limits");
  el.className = bad ? "violation" : "";
  document.getElementById("title").textContent = d.source;
}

// What moves with the slider at sample `index` of the first run: the cone, each group's deputy
// markers and the virtual target, as {traces, x, y, z} for Plotly.restyle; the cursor's time.
function moving(d, index) {
  const t = d.runs[0].t[index];
  const cone = coneLines(d.scene, axisAt(d, index));
  const traces = [0], x = [cone.x], y = [cone.y], z = [cone.z];
  view.groups.forEach(([, runs], n) => {
    const gx = [], gy = [], gz = [];
    for (const r of runs) {
      const i = nearest(r.t, t);
      gx.push(r.deputy[0][i]); gy.push(r.deputy[1][i]); gz.push(r.deputy[2][i]);
    }
    traces.push(view.markerTraces[n]); x.push(gx); y.push(gy); z.push(gz);
  });
  if (view.targetTrace !== null) {
    const tg = d.runs[0].target;
    traces.push(view.targetTrace);
    x.push([tg[0][index]]); y.push([tg[1][index]]); z.push([tg[2][index]]);
  }
  return {t, traces, x, y, z};
}

function label(d, index) {
  const t = d.runs[0].t[index];
  const tau = d.runs.length === 1 && d.runs[0].values.tau ? d.runs[0].values.tau[index] : null;
  document.getElementById("time").textContent =
    `t = ${clock(t)}` + (tau === null || tau === undefined ? "" : ` · tau = ${tau.toFixed(2)} s`);
}

function setIndex(index) {
  const d = view.data;
  view.index = index;
  const m = moving(d, index);
  Plotly.restyle("scene", {x: m.x, y: m.y, z: m.z}, m.traces);
  Plotly.relayout("plots", {"shapes[0].x0": m.t / 3600, "shapes[0].x1": m.t / 3600});
  label(d, index);
}

async function render(d) {
  view.data = d;
  view.groups = [...groupsOf(d.runs)];
  const n = d.runs[0].t.length;
  view.index = d.kind === "live" && view.following ? n - 1 : Math.min(view.index, n - 1);
  const s = sceneFigure(d), p = plotsFigure(d), m = moving(d, view.index);
  m.traces.forEach((trace, i) => Object.assign(s.traces[trace], {x: m.x[i], y: m.y[i], z: m.z[i]}));
  Object.assign(p.layout.shapes[0], {x0: m.t / 3600, x1: m.t / 3600});
  const t0 = performance.now();
  await Plotly.react("scene", s.traces, s.layout, {responsive: true});
  const t1 = performance.now();
  await Plotly.react("plots", p.traces, p.layout, {responsive: true});
  view.renderMs = {data: t0, scene: t1 - t0, plots: performance.now() - t1};
  slider.max = String(n - 1);
  slider.value = String(view.index);
  label(d, view.index);
  status(d);
  view.shown = d;  // the data the page now draws (view.data is set before the plots are redrawn)
}

slider.addEventListener("input", () => {
  const i = Number(slider.value);
  view.following = i === Number(slider.max);
  setIndex(i);
});

// The data and its version (the server's X-View-Version header); the first from the request the
// page made while plotly.js loaded.
async function fetchData() {
  const r = await (window.cikanPrefetch || fetch("data.json", {cache: "no-store"}));
  window.cikanPrefetch = null;
  if (!r.ok) throw new Error(`data.json: HTTP ${r.status}`);
  return {version: Number(r.headers.get("X-View-Version")), data: await r.json()};
}

async function poll() {
  try {
    const v = view.version ? await fetchJSON("version") : {version: -1};
    if (v.version !== view.version) {
      const {version, data} = await fetchData();
      view.version = version;
      if (data) {
        await render(data);
        if (!view.ready) {
          view.loadMs = performance.now();
          view.ready = true;
        }
      } else {
        document.getElementById("status").textContent = "waiting for the mission's first time shift";
      }
    }
    if (view.data && view.data.complete) return;
  } catch (err) {
    document.getElementById("status").textContent = `no answer from the view (${err.message}); retrying`;
  }
  setTimeout(poll, POLL_MS);
}

poll();
