// A small orbitable 3D view on a 2D canvas: perspective projection of polylines and points.
// World = the sonar frame (X right, Y forward, Z up), metres.

export class View3D {
  constructor(canvas) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.yaw = -0.6; this.pitch = 0.45; this.dist = 14; this.target = [0, 6, 0];
    this.data = null;
    let drag = null;
    canvas.addEventListener("pointerdown", (e) => { drag = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId); });
    canvas.addEventListener("pointermove", (e) => {
      if (!drag) return;
      this.yaw += (e.clientX - drag[0]) * 0.01;
      this.pitch = Math.max(-1.5, Math.min(1.5, this.pitch + (e.clientY - drag[1]) * 0.01));
      drag = [e.clientX, e.clientY];
      this.draw();
    });
    canvas.addEventListener("pointerup", () => { drag = null; });
    canvas.addEventListener("wheel", (e) => {
      e.preventDefault();
      this.dist = Math.max(0.5, Math.min(200, this.dist * Math.exp(e.deltaY * 0.001)));
      this.draw();
    }, { passive: false });
  }

  setData(data) {
    const hadPoints = this.data !== null && this.data.points.length > 0;
    const first = this.data === null;
    this.data = data;
    const pts = data.points.map((p) => p.p);
    if (pts.length && !hadPoints) {
      // frame the points when they first appear
      this.target = [0, 1, 2].map((k) => pts.reduce((s, p) => s + p[k], 0) / pts.length);
      this.dist = Math.max(2, 0.8 * Math.hypot(...this.target));
    } else if (!pts.length && (first || hadPoints)) {
      // frame the whole fan
      this.target = [0, data.range_max / 2, 0];
      this.dist = 1.4 * data.range_max;
    }
    this.draw();
  }

  // world -> canvas pixels (or null behind the eye)
  project(p) {
    const cy = Math.cos(this.yaw), sy = Math.sin(this.yaw), cp = Math.cos(this.pitch), sp = Math.sin(this.pitch);
    const d = [p[0] - this.target[0], p[1] - this.target[1], p[2] - this.target[2]];
    // view axes: right, up, forward of an eye orbiting the target
    const x = cy * d[0] + sy * d[1];
    const yy = -sy * d[0] + cy * d[1];
    const up = cp * d[2] - sp * yy;
    const fwd = sp * d[2] + cp * yy + this.dist;
    if (fwd < 0.05) return null;
    const f = 0.9 * this.canvas.height;
    return [this.canvas.width / 2 + (f * x) / fwd, this.canvas.height / 2 - (f * up) / fwd];
  }

  line(pts, color, width = 1, dash = []) {
    const c = this.ctx;
    c.strokeStyle = color; c.lineWidth = width; c.setLineDash(dash);
    c.beginPath();
    let pen = false;
    for (const p of pts) {
      const q = this.project(p);
      if (!q) { pen = false; continue; }
      if (pen) c.lineTo(q[0], q[1]); else c.moveTo(q[0], q[1]);
      pen = true;
    }
    c.stroke();
    c.setLineDash([]);
  }

  draw() {
    const c = this.ctx, W = this.canvas.width, H = this.canvas.height;
    c.fillStyle = "#07090b"; c.fillRect(0, 0, W, H);
    if (!this.data) return;
    // sonar axes (1 m)
    this.line([[0, 0, 0], [1, 0, 0]], "#e05050", 2);
    this.line([[0, 0, 0], [0, 1, 0]], "#50c050", 2);
    this.line([[0, 0, 0], [0, 0, 1]], "#5080f0", 2);
    for (const l of this.data.fan) this.line(l, "rgba(255,179,71,0.45)", 1);
    for (const l of this.data.frustum) this.line(l, "rgba(127,219,255,0.8)", 1.2);
    const colors = window.matchColors || ["#fff"];
    // what each sensor alone knows of a match: the sonar's elevation arc, the camera's ray
    for (const m of this.data.matches || []) {
      const col = colors[m.index % colors.length];
      this.line(m.arc, col, 1, [4, 3]);
      this.line(m.ray, col, 0.7, [1, 3]);
    }
    for (const p of this.data.points) {
      const col = colors[p.index % colors.length];
      for (const a of p.axes) this.line([[p.p[0] - a[0], p.p[1] - a[1], p.p[2] - a[2]], [p.p[0] + a[0], p.p[1] + a[1], p.p[2] + a[2]]], col, 1.5);
      const q = this.project(p.p);
      if (q) {
        c.fillStyle = col; c.beginPath(); c.arc(q[0], q[1], 3.5, 0, 2 * Math.PI); c.fill();
        c.fillStyle = "#fff"; c.font = "12px system-ui"; c.fillText(String(p.index + 1), q[0] + 5, q[1] - 5);
      }
    }
    c.fillStyle = "#9aa3ad"; c.font = "11px system-ui";
    c.fillText("sonar axes X red, Y green, Z blue (1 m); sonar fan amber; camera frustum cyan", 8, H - 22);
    c.fillText("per match: sonar elevation arc (dashed), camera ray (dotted), the point and its 3-sigma CRLB axes", 8, H - 8);
  }
}
