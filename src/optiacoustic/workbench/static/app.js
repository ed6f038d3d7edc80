// The workbench page: two zoomable images, epipolar curves from the server, matches, 3D, calibration, fusion.
import { get, post, put, del, withToken } from "./api.js";
import { View3D } from "./view3d.js";

const SVGNS = "http://www.w3.org/2000/svg";
const COLORS = ["#e6194b", "#3cb44b", "#ffe119", "#4363d8", "#f58231", "#911eb4", "#46f0f0", "#f032e6", "#bcf60c", "#fabebe"];
window.matchColors = COLORS;
const $ = (id) => document.getElementById(id);

const state = { server: null, mode: "match", pending: { sonar: null, camera: null }, selected: null, recon: null };

function status(msg, error = false) {
  const s = $("status");
  s.textContent = msg;
  s.classList.toggle("error", error);
}

async function guarded(fn) {
  try { return await fn(); } catch (e) { status(e.message, true); return undefined; }
}

// ---------------------------------------------------------------- zoomable, pannable image panels
class Panel {
  constructor(side) {
    this.side = side;
    this.svg = $(side + "-svg");
    this.img = $(side + "-img");
    this.hover = this.svg.querySelector(".hover");
    this.pinned = this.svg.querySelector(".pinned");
    this.marks = this.svg.querySelector(".marks");
    this.w = 1; this.h = 1;
    this.view = { x: 0, y: 0, w: 1, h: 1 };
    this.install();
  }

  setImage(url, w, h) {
    this.w = w; this.h = h;
    this.img.setAttribute("href", withToken(url));
    this.img.setAttribute("width", w); this.img.setAttribute("height", h);
    const f = this.svg.querySelector("#fusion-img");
    if (f) { f.setAttribute("width", w); f.setAttribute("height", h); }
    this.reset();
  }

  reset() { this.view = { x: -0.5, y: -0.5, w: this.w, h: this.h }; this.apply(); }

  apply() {
    const v = this.view;
    this.svg.setAttribute("viewBox", `${v.x} ${v.y} ${v.w} ${v.h}`);
    this.onview && this.onview();
  }

  // screen units per image pixel
  scale() {
    const r = this.svg.getBoundingClientRect();
    return Math.min(r.width / this.view.w, r.height / this.view.h) || 1;
  }

  toImage(evt) {
    const p = this.svg.createSVGPoint();
    p.x = evt.clientX; p.y = evt.clientY;
    const q = p.matrixTransform(this.svg.getScreenCTM().inverse());
    return [q.x, q.y];
  }

  inside(pt) { return pt[0] >= -0.5 && pt[1] >= -0.5 && pt[0] <= this.w - 0.5 && pt[1] <= this.h - 0.5; }

  install() {
    const svg = this.svg;
    let drag = null;
    svg.addEventListener("wheel", (e) => {
      e.preventDefault();
      const [x, y] = this.toImage(e);
      const k = Math.exp(e.deltaY * 0.0015);
      const v = this.view;
      const w = Math.min(this.w * 4, Math.max(8, v.w * k));
      const s = w / v.w;
      this.view = { x: x - (x - v.x) * s, y: y - (y - v.y) * s, w, h: v.h * s };
      this.apply();
    }, { passive: false });
    svg.addEventListener("pointerdown", (e) => {
      const mark = e.target.closest && e.target.closest(".mark");
      drag = { x: e.clientX, y: e.clientY, moved: false, view: { ...this.view }, mark: mark ? Number(mark.dataset.index) : null };
      svg.setPointerCapture(e.pointerId);
    });
    svg.addEventListener("pointermove", (e) => {
      if (drag) {
        const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
        if (Math.hypot(dx, dy) > 3) drag.moved = true;
        if (drag.moved && drag.mark === null) {
          svg.classList.add("panning");
          const s = this.scale();
          this.view = { ...drag.view, x: drag.view.x - dx / s, y: drag.view.y - dy / s };
          this.apply();
        } else if (drag.moved && drag.mark !== null) {
          this.onmarkdrag && this.onmarkdrag(drag.mark, this.toImage(e));
        }
        return;
      }
      const pt = this.toImage(e);
      this.onhover && this.onhover(pt);
    });
    svg.addEventListener("pointerup", (e) => {
      svg.classList.remove("panning");
      const d = drag; drag = null;
      if (!d) return;
      const pt = this.toImage(e);
      if (d.mark !== null && d.moved) this.onmarkdrop && this.onmarkdrop(d.mark, pt);
      else if (d.mark !== null) this.onmarkclick && this.onmarkclick(d.mark);
      else if (!d.moved) this.onclick && this.onclick(pt);
    });
    svg.addEventListener("pointerleave", () => { this.hover.replaceChildren(); });
    svg.addEventListener("dblclick", () => this.reset());
  }
}

function polyline(points, cls, color) {
  const el = document.createElementNS(SVGNS, "polyline");
  el.setAttribute("points", points.map((p) => p[0] + "," + p[1]).join(" "));
  el.setAttribute("class", "curve " + cls);
  if (color) el.setAttribute("stroke", color);
  return el;
}

function drawCurves(group, curves, color, tag) {
  const g = document.createElementNS(SVGNS, "g");
  if (tag) g.dataset.curve = tag;
  for (const line of curves.dashed || []) g.appendChild(polyline(line, "dashed", color));
  for (const line of curves.solid || []) g.appendChild(polyline(line, "solid", color));
  group.appendChild(g);
}

const panels = { sonar: new Panel("sonar"), camera: new Panel("camera") };
const other = { sonar: "camera", camera: "sonar" };
const view3d = new View3D($("view3d"));

// ---------------------------------------------------------------- curves
let hoverBusy = false, hoverNext = null;
async function curve(side, pt) {
  return get(`/api/curve?side=${side}&u=${pt[0].toFixed(3)}&v=${pt[1].toFixed(3)}`);
}

async function hoverCurve(side, pt) {
  if (!panels[side].inside(pt)) return;
  if (hoverBusy) { hoverNext = [side, pt]; return; }
  hoverBusy = true;
  try {
    const c = await curve(side, pt);
    const g = panels[other[side]].hover;
    g.replaceChildren();
    drawCurves(g, c, null, "hover");
    readout(side, pt, c);
  } catch (e) {
    panels[other[side]].hover.replaceChildren();
    readout(side, pt, null, e.message);
  } finally {
    hoverBusy = false;
    if (hoverNext) { const n = hoverNext; hoverNext = null; hoverCurve(...n); }
  }
}

function readout(side, pt, c, err) {
  let s = `${side} (${pt[0].toFixed(1)}, ${pt[1].toFixed(1)}) px`;
  if (c && c.range !== undefined) s += ` = range ${c.range.toFixed(3)} m, azimuth ${c.azimuth_deg.toFixed(2)} deg; conic: ${c.conic_type}`;
  if (err) s += ` (${err})`;
  $(side + "-readout").textContent = s;
}

// pinned curves: the pending point's, and the selected match's
async function redrawPinned() {
  for (const s of ["sonar", "camera"]) panels[s].pinned.replaceChildren();
  const jobs = [];
  for (const side of ["sonar", "camera"]) {
    const p = state.pending[side];
    if (p) jobs.push(curve(side, p).then((c) => drawCurves(panels[other[side]].pinned, c, "#ffffff", "pending-" + side)));
  }
  const m = state.selected !== null && state.server ? state.server.matches[state.selected] : null;
  if (m) {
    const col = COLORS[m.index % COLORS.length];
    jobs.push(curve("sonar", m.sonar).then((c) => drawCurves(panels.camera.pinned, c, col, "match-" + m.index)));
    jobs.push(curve("camera", m.camera).then((c) => drawCurves(panels.sonar.pinned, c, col, "match-" + m.index)));
  }
  await guarded(() => Promise.all(jobs));
}

// ---------------------------------------------------------------- marks
function drawMarks() {
  for (const side of ["sonar", "camera"]) {
    const p = panels[side];
    const s = p.scale(), r = 7 / s, fs = 13 / s;
    p.marks.replaceChildren();
    for (const m of state.server ? state.server.matches : []) {
      const [x, y] = m[side];
      const c = document.createElementNS(SVGNS, "circle");
      c.setAttribute("cx", x); c.setAttribute("cy", y); c.setAttribute("r", r);
      c.setAttribute("class", "mark" + (m.index === state.selected ? " selected" : ""));
      c.setAttribute("stroke", COLORS[m.index % COLORS.length]);
      if (m.index === state.selected) c.setAttribute("stroke-width", "4");
      c.dataset.index = m.index;
      p.marks.appendChild(c);
      const t = document.createElementNS(SVGNS, "text");
      t.setAttribute("x", x + r); t.setAttribute("y", y - r); t.setAttribute("class", "mark-label");
      t.setAttribute("fill", COLORS[m.index % COLORS.length]); t.setAttribute("font-size", fs); t.setAttribute("stroke-width", 3 / s);
      t.textContent = String(m.index + 1);
      p.marks.appendChild(t);
    }
    const q = state.pending[side];
    if (q) {
      const c = document.createElementNS(SVGNS, "circle");
      c.setAttribute("cx", q[0]); c.setAttribute("cy", q[1]); c.setAttribute("r", r);
      c.setAttribute("class", "mark pending");
      p.marks.appendChild(c);
    }
  }
}
panels.sonar.onview = drawMarks;
panels.camera.onview = drawMarks;

// ---------------------------------------------------------------- state from the server
const fmt = (x, d = 3) => (x === null || x === undefined ? "-" : Number(x).toFixed(d));

async function refresh() {
  const st = await get("/api/state");
  const sourceChanged = !state.server || state.server.source.name !== st.source.name || state.server.source.description !== st.source.description;
  state.server = st;
  if (sourceChanged) {
    panels.sonar.setImage("/api/image/sonar.png?s=" + encodeURIComponent(st.source.description), st.fan.width, st.fan.height);
    panels.camera.setImage("/api/image/camera.png?s=" + encodeURIComponent(st.source.description), st.camera.width, st.camera.height);
    fillSources(st);
    $("fusion-img").setAttribute("visibility", "hidden");
  }
  if (state.selected !== null && state.selected >= st.matches.length) state.selected = null;
  $("sonar-info").textContent = `${st.sonar.name}: ${st.sonar.fov_azimuth_deg.toFixed(0)} x ${st.sonar.fov_elevation_deg.toFixed(0)} deg, ${(+st.sonar.range_min).toFixed(2)}-${(+st.sonar.range_max).toFixed(2)} m`;
  $("camera-info").textContent = `${st.camera.width} x ${st.camera.height} px, f = ${st.camera.fx.toFixed(0)} px`;
  if (sourceChanged) {  // the noise fields are the user's once the pair is loaded
    $("sig-px").value = st.sigmas.pixel; $("sig-r").value = st.sigmas.range; $("sig-a").value = +st.sigmas.azimuth_deg.toFixed(4);
  }
  const rig = st.rig;
  $("rig-info").textContent = `rig${rig.calibrated ? " (calibrated)" : ""}: t = (${rig.t.map((x) => x.toFixed(3)).join(", ")}) m, ` +
    `rotation about sonar x, y, z = (${rig.rotation_about_sonar_xyz_deg.map((x) => x.toFixed(2)).join(", ")}) deg, baseline ${rig.baseline_m.toFixed(3)} m. ` +
    `Source: ${st.source.description}`;
  $("undo").disabled = !st.can_undo;
  $("suggest").disabled = !st.matcher.available;
  $("suggest").title = st.matcher.message;
  drawMarks();
  renderViews(st);
  await Promise.all([redrawPinned(), reconstruct()]);
}

async function reconstruct() {
  const rec = await get("/api/reconstruction");
  state.recon = rec;
  $("recon-msg").textContent = rec.n ? "ML reconstruction: " + rec.message : "click a point in either image, then its mate in the other";
  const tb = $("matches").querySelector("tbody");
  tb.replaceChildren();
  for (const m of state.server.matches) {
    const p = rec.points[m.index] || {};
    const tr = document.createElement("tr");
    tr.dataset.index = m.index;
    if (m.index === state.selected) tr.classList.add("selected");
    const bad = p.distance_sigma !== null && p.distance_sigma > 3;
    const cells = [
      `<span style="color:${COLORS[m.index % COLORS.length]}">&#9679;</span> ${m.index + 1}`,
      `${fmt(m.camera[0], 1)}, ${fmt(m.camera[1], 1)}`, fmt(m.range), fmt(m.azimuth_deg, 2),
      fmt(p.distance_px, 2), fmt(p.distance_sigma, 2),
      p.valid ? p.point_sonar.map((x) => fmt(x)).join(", ") : p.status || "-",
      p.valid ? p.std_sonar.map((x) => fmt(1000 * x, 1)).join(", ") : "-",
    ];
    tr.innerHTML = cells.map((c, k) => `<td${k === 5 && bad ? ' class="bad"' : ""}>${c}</td>`).join("");
    tr.addEventListener("click", () => select(m.index));
    tb.appendChild(tr);
  }
  view3d.setData(await get("/api/scene3d"));
}

function select(i) {
  state.selected = state.selected === i ? null : i;
  drawMarks();
  reconstruct();
  redrawPinned();
}

// ---------------------------------------------------------------- picking matches
async function pick(side, pt) {
  if (!panels[side].inside(pt)) return;
  if (side === "sonar") {
    // reject points outside the fan at once (the server says why)
    try { await curve("sonar", pt); } catch (e) { status(e.message, true); return; }
  }
  state.pending[side] = pt;
  const o = other[side];
  if (state.pending[o]) {
    const body = { sonar: { u: state.pending.sonar[0], v: state.pending.sonar[1] }, camera: { u: state.pending.camera[0], v: state.pending.camera[1] } };
    state.pending = { sonar: null, camera: null };
    const r = await guarded(() => post("/api/matches", body));
    if (r) { state.selected = r.index; status(`match ${r.index + 1} added`); }
    await refresh();
  } else {
    status(`${side} point picked: now click its mate on the curve in the ${o} image (Esc cancels)`);
    drawMarks();
    redrawPinned();
  }
}

for (const side of ["sonar", "camera"]) {
  const p = panels[side];
  p.onhover = (pt) => hoverCurve(side, pt);
  p.onclick = (pt) => pick(side, pt);
  p.onmarkclick = (i) => select(i);
  p.onmarkdrag = (i, pt) => {
    const c = p.marks.querySelector(`circle[data-index="${i}"]`);
    if (c) { c.setAttribute("cx", pt[0]); c.setAttribute("cy", pt[1]); }
    hoverCurve(side, pt);
  };
  p.onmarkdrop = async (i, pt) => {
    await guarded(() => put(`/api/matches/${i}`, { [side]: { u: pt[0], v: pt[1] } }));
    state.selected = i;
    await refresh();
  };
}

async function undo() { await guarded(() => post("/api/undo")); await refresh(); status("undone"); }
async function deleteSelected() {
  if (state.selected === null) { status("select a match first (click its marker or row)", true); return; }
  await guarded(() => del(`/api/matches/${state.selected}`));
  status(`match ${state.selected + 1} deleted`);
  state.selected = null;
  await refresh();
}
$("undo").addEventListener("click", undo);
$("suggest").addEventListener("click", async () => {
  status("matching automatically ...");
  const r = await guarded(() => post("/api/matches/suggest"));
  if (r) status(r.added ? `${r.added} suggested matches added (${r.message}); Undo removes them`
                        : `no matches suggested: ${r.message}`);
  await refresh();
});
$("delete").addEventListener("click", deleteSelected);
$("clear").addEventListener("click", async () => { await guarded(() => post("/api/matches/clear")); state.selected = null; await refresh(); });
document.addEventListener("keydown", (e) => {
  if (e.target.tagName === "INPUT") return;
  if ((e.ctrlKey || e.metaKey) && e.key === "z") { e.preventDefault(); undo(); }
  else if (e.key === "Delete" || e.key === "Backspace") deleteSelected();
  else if (e.key === "Escape") { state.pending = { sonar: null, camera: null }; drawMarks(); redrawPinned(); status(""); }
});

// ---------------------------------------------------------------- settings, import
for (const id of ["sig-px", "sig-r", "sig-a"]) {
  $(id).addEventListener("change", async () => {
    const body = { pixel: +$("sig-px").value, range: +$("sig-r").value, azimuth_deg: +$("sig-a").value };
    await guarded(() => post("/api/settings", body));
    await refresh();
  });
}

async function readFile(input) {
  const f = input.files[0];
  input.value = "";
  return f ? { text: await f.text(), name: f.name } : null;
}
$("import-csv").addEventListener("change", async (e) => {
  const f = await readFile(e.target);
  if (!f) return;
  const r = await guarded(() => post("/api/import/matches", f));
  if (r) status(`imported ${r.n} matches from ${f.name}`);
  state.selected = null;
  await refresh();
});
for (const id of ["export-csv", "export-ply", "export-png"]) {
  $(id).addEventListener("click", (e) => { e.currentTarget.href = withToken(e.currentTarget.getAttribute("href").split("?")[0]); });
}

// ---------------------------------------------------------------- sources
function fillSources(st) {
  const sel = $("source");
  sel.replaceChildren();
  const add = (value, label, disabled = false, title = "") => {
    const o = document.createElement("option");
    o.value = value; o.textContent = label; o.disabled = disabled; o.title = title;
    sel.appendChild(o);
  };
  for (const n of st.sources.extra) add(n, n);
  for (const n of st.sources.scenes) add(n, "simulated: " + n);
  const how = { real: "start with oas workbench --sonar-log LOG --camera-log LOG --rig RIG",
                dataset: "start with oas workbench DATASET_FOLDER --frame N" };
  for (const k of ["real", "dataset"]) {
    const info = st.sources.kinds[k];
    const label = k === "real" ? "real pair" : "dataset frame";
    if (!info.available) add("", `${label}: not available`, true, info.message);
    else if (!(st.source.kind === k)) add("", `${label}: ${how[k]}`, true, info.message);
  }
  $("frame-box").hidden = st.source.n_frames <= 1;
  $("frame").max = st.source.n_frames - 1;
  $("frame").value = st.source.frame;
  $("frame-count").textContent = `of ${st.source.n_frames}`;
  const cur = st.sources.current;
  sel.value = [...sel.options].some((o) => o.value === cur) ? cur : st.sources.extra[0] || "";
  const na = Object.entries(st.sources.kinds).filter(([, v]) => !v.available).map(([, v]) => v.message);
  if (!st.matcher.available) na.push(st.matcher.message);
  $("source-note").textContent = na.length ? na.join("; ") : "";
}
$("frame").addEventListener("change", async (e) => {
  const k = Math.round(+e.target.value);
  status(`loading frame ${k} ...`);
  state.selected = null; state.pending = { sonar: null, camera: null };
  const r = await guarded(() => post("/api/source", { name: state.server.sources.current, frame: k }));
  if (r) status(`frame ${k}: matches start afresh; calibration views and an applied rig are kept`);
  state.server = null;
  await refresh();
});
$("source").addEventListener("change", async (e) => {
  status("loading " + e.target.value + " ...");
  state.selected = null; state.pending = { sonar: null, camera: null };
  const r = await guarded(() => post("/api/source", { name: e.target.value }));
  if (r) status("loaded " + e.target.value);
  state.server = null;
  await refresh();
});

// ---------------------------------------------------------------- modes
function setMode(mode) {
  state.mode = mode;
  for (const b of document.querySelectorAll("#modes button")) b.classList.toggle("active", b.dataset.mode === mode);
  $("calib-pane").hidden = mode !== "calibrate";
  $("fusion-pane").hidden = mode !== "fusion";
  $("fusion-img").setAttribute("visibility", mode === "fusion" && $("fusion-img").getAttribute("href") ? "visible" : "hidden");
}
for (const b of document.querySelectorAll("#modes button")) b.addEventListener("click", () => setMode(b.dataset.mode));

// calibration
function renderViews(st) {
  const ul = $("views");
  ul.replaceChildren();
  for (const v of st.views) {
    const li = document.createElement("li");
    li.textContent = `view ${v.index + 1}: ${v.n} corners`;
    const b = document.createElement("button");
    b.textContent = "\u00d7";
    b.title = "remove this view";
    b.addEventListener("click", async () => { await guarded(() => del(`/api/calibration/views/${v.index}`)); await refresh(); });
    li.appendChild(b);
    ul.appendChild(li);
  }
  renderReport(st.calibration);
}

function renderReport(rep) {
  const el = $("calib-report");
  if (!rep) { el.innerHTML = ""; return; }
  if (!rep.success) { el.innerHTML = `<p class="note">calibration failed: ${rep.message}</p>`; return; }
  const names = ["pitch", "roll", "yaw", "t_x", "t_y", "t_z"];
  const vals = [...rep.rotation_about_sonar_xyz_deg, ...rep.t.map((x) => 1000 * x)];
  const rows = names.map((n, i) => `<tr><td>${n} (${i < 3 ? "deg" : "mm"})</td><td>${vals[i].toFixed(i < 3 ? 3 : 1)}</td>` +
    `<td>${rep.std[n].toFixed(i < 3 ? 3 : 1)}</td><td>${rep.weak.includes(n) ? "weak" : ""}</td></tr>`).join("");
  el.innerHTML = `<p>${rep.message}</p><table><thead><tr><th>degree of freedom</th><th>value</th><th>std</th><th>observability</th></tr></thead>` +
    `<tbody>${rows}</tbody></table><p class="note">${rep.weak.length ? "Weakly observed: " + rep.weak.join(", ") +
    " (the sonar does not measure elevation: tilt the grid and fill the elevation aperture)." : "All directions well observed."}` +
    ` chi2 = ${rep.chi2.toFixed(1)} on ${rep.dof} dof; rms ${rep.rms_pixel.toFixed(2)} px, ${rep.rms_range_mm.toFixed(1)} mm, ${rep.rms_azimuth_deg.toFixed(3)} deg.</p>`;
}

$("add-view").addEventListener("click", async () => {
  const r = await guarded(() => post("/api/calibration/views"));
  if (r) status(`view ${r.index + 1} added; its matches were cleared for the next view`);
  await refresh();
});
$("import-views").addEventListener("change", async (e) => {
  const files = [...e.target.files];
  e.target.value = "";
  let n = 0;
  for (const f of files) {
    const r = await guarded(async () => post("/api/calibration/import", { text: await f.text(), name: f.name }));
    if (r) n += 1;
  }
  status(`imported ${n} view(s)`);
  await refresh();
});
$("run-calib").addEventListener("click", async () => {
  status("calibrating ...");
  const r = await guarded(() => post("/api/calibration/run"));
  if (r) status(r.success ? "calibrated: " + r.message : "calibration failed: " + r.message, !r.success);
  await refresh();
});
$("apply-calib").addEventListener("click", async () => {
  const r = await guarded(() => post("/api/calibration/apply"));
  if (r) status("the calibrated rig now drives the curves and the reconstruction");
  await refresh();
});
$("reset-rig").addEventListener("click", async () => { await guarded(() => post("/api/rig/reset")); status("rig reset to the source's"); await refresh(); });

// fusion
$("fusion-update").addEventListener("click", async () => {
  const m = $("mapping").value;
  status(`mapping the sonar into the camera (${m}) ...`);
  const url = withToken(`/api/fusion.png?mapping=${m}`);
  const resp = await fetch(url);
  if (!resp.ok) { const d = await resp.json().catch(() => ({})); status(d.error || resp.statusText, true); return; }
  const blob = await resp.blob();
  const img = $("fusion-img");
  const old = img.getAttribute("href");
  if (old && old.startsWith("blob:")) URL.revokeObjectURL(old);
  img.setAttribute("href", URL.createObjectURL(blob));
  img.setAttribute("visibility", "visible");
  $("fusion-msg").textContent = resp.headers.get("x-mapping") || "";
  status("overlay: " + (resp.headers.get("x-mapping") || m));
});
$("opacity").addEventListener("input", (e) => $("fusion-img").setAttribute("opacity", e.target.value));

// ---------------------------------------------------------------- start
(async () => {
  await guarded(refresh);
  const sel = $("mapping");
  for (const m of state.server.mappings) { const o = document.createElement("option"); o.value = m; o.textContent = m; sel.appendChild(o); }
  status("hover over either image to see the epipolar curve in the other; click a point, then its mate");
  document.body.dataset.ready = "1";
})();
