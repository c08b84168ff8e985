// igi viewer: live frames over a WebSocket, camera controls, a parameter panel generated from
// the server's declarations, object selection and moves, stats. Plain JS, no build step.
// Protocol: see master/viewer.py (module docstring) and docs/viewer.md.
"use strict";
(() => {
  const $ = (id) => document.getElementById(id);
  const token = new URLSearchParams(location.search).get("token");
  const withToken = (path) => (token ? `${path}${path.includes("?") ? "&" : "?"}token=${encodeURIComponent(token)}` : path);

  // ------------------------------------------------------------------ small vector algebra
  const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
  const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
  const mul = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const len = (a) => Math.sqrt(dot(a, a));
  const norm = (a) => { const l = len(a); return l > 0 ? mul(a, 1 / l) : a; };
  function rotate(v, axis, ang) { // Rodrigues, unit axis
    const c = Math.cos(ang), s = Math.sin(ang);
    return add(add(mul(v, c), mul(cross(axis, v), s)), mul(axis, dot(axis, v) * (1 - c)));
  }

  // ------------------------------------------------------------------ state
  const canvas = $("view");
  const ctx = canvas.getContext("2d");
  const stage = $("stage");
  const dbg = {  // read by the tests (tests/test_viewer.py)
    frames: 0, seq: 0, generation: -1, accumulated: 0, header: null, selection: null, version: 0,
    connected: false, errors: [], stats: null, params: null, cameraSent: 0, movesSent: 0, lastCamera: null,
    snapshot: () => Array.from(ctx.getImageData(0, 0, canvas.width, canvas.height).data),
  };
  window.igi = dbg;
  let ws = null;
  let schema = [];
  let scene = null;  // objects, centre, diagonal
  const cam = { origin: [0, 0, 0], fwd: [0, 0, 1], up: [0, 1, 0], left: [1, 0, 0], pivot: [0, 0, 1],
                worldUp: [0, 1, 0], fov: 40, ready: false };
  let imgW = 1, imgH = 1;

  function send(obj) {
    if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(obj));
  }
  let msgTimer = null;
  function say(text, isError) {
    $("message").textContent = text;
    if (isError) dbg.errors.push(text);
    clearTimeout(msgTimer);
    msgTimer = setTimeout(() => { $("message").textContent = ""; }, 5000);
  }

  // ------------------------------------------------------------------ camera
  function setCamera(m, fov) { // m: 16 floats row-major, Mitsuba to_world (columns: left, up, forward, origin)
    const col = (j) => [m[j], m[4 + j], m[8 + j]];
    cam.left = norm(col(0)); cam.up = norm(col(1)); cam.fwd = norm(col(2)); cam.origin = col(3);
    cam.fov = fov;
    if (!cam.ready) {
      cam.worldUp = cam.up;
      const c = scene ? scene.center : add(cam.origin, cam.fwd);
      let d = dot(sub(c, cam.origin), cam.fwd);
      if (!(d > 1e-6)) d = scene ? scene.diagonal * 0.5 : 1;
      cam.pivot = add(cam.origin, mul(cam.fwd, d));
      cam.ready = true;
    }
  }
  function rebuild() {
    cam.fwd = norm(sub(cam.pivot, cam.origin));
    const l = cross(cam.worldUp, cam.fwd);
    if (len(l) > 1e-9) cam.left = norm(l);
    cam.up = cross(cam.fwd, cam.left);
  }
  function toWorld() {
    const { left: l, up: u, fwd: f, origin: o } = cam;
    return [l[0], u[0], f[0], o[0], l[1], u[1], f[1], o[1], l[2], u[2], f[2], o[2], 0, 0, 0, 1];
  }
  const dist = () => len(sub(cam.pivot, cam.origin));
  const diag = () => (scene ? scene.diagonal : 1);
  const pixelWorld = (d) => (2 * d * Math.tan((cam.fov * Math.PI) / 360)) / Math.max(1, canvas.clientWidth);

  function orbit(dx, dy) {
    let off = sub(cam.origin, cam.pivot);
    off = rotate(off, norm(cam.worldUp), -dx * 0.006);
    const leftAxis = norm(cross(cam.worldUp, mul(off, -1)));
    const tilted = rotate(off, leftAxis, dy * 0.006);
    if (Math.abs(dot(norm(tilted), norm(cam.worldUp))) < 0.995) off = tilted;
    cam.origin = add(cam.pivot, off);
    rebuild();
    cameraChanged();
  }
  function pan(dx, dy) {
    const s = pixelWorld(dist());
    const d = add(mul(cam.left, dx * s), mul(cam.up, dy * s));
    cam.origin = add(cam.origin, d); cam.pivot = add(cam.pivot, d);
    cameraChanged();
  }
  function zoom(steps) {
    const d = Math.min(Math.max(dist() * Math.pow(1.12, steps), diag() * 1e-3), diag() * 50);
    cam.origin = sub(cam.pivot, mul(cam.fwd, d));
    cameraChanged();
  }
  function fly(vec) {
    cam.origin = add(cam.origin, vec); cam.pivot = add(cam.pivot, vec);
    cameraChanged();
  }

  let camTimer = null, camLast = 0, camDirty = false;
  const CAMERA_INTERVAL = 80; // ms between camera messages while moving (each restarts the frame)
  function cameraChanged() {
    camDirty = true;
    const wait = CAMERA_INTERVAL - (performance.now() - camLast);
    if (wait <= 0) flushCamera();
    else if (!camTimer) camTimer = setTimeout(flushCamera, wait);
  }
  function flushCamera() {
    camTimer = null;
    if (!camDirty) return;
    camDirty = false; camLast = performance.now();
    dbg.cameraSent++;
    dbg.lastCamera = toWorld();
    send({ type: "camera", to_world: dbg.lastCamera, fov_x: cam.fov });
  }

  // ------------------------------------------------------------------ frames
  let drawChain = Promise.resolve();
  function onFrame(buf) {
    const dv = new DataView(buf);
    const n = dv.getUint32(0);
    const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n)));
    const blob = new Blob([new Uint8Array(buf, 4 + n)], { type: header.mime });
    drawChain = drawChain
      .then(() => createImageBitmap(blob))
      .then((bmp) => {
        if (canvas.width !== bmp.width || canvas.height !== bmp.height) {
          canvas.width = bmp.width; canvas.height = bmp.height; imgW = bmp.width; imgH = bmp.height;
          fitCanvas();
        }
        ctx.drawImage(bmp, 0, 0);
        bmp.close && bmp.close();
        dbg.frames++; dbg.seq = header.seq; dbg.generation = header.generation;
        dbg.accumulated = header.accumulated; dbg.header = header;
      })
      .catch((e) => say(`frame: ${e}`, true))
      .finally(() => send({ type: "ack", seq: header.seq }));
  }
  function fitCanvas() {
    const r = stage.getBoundingClientRect();
    const s = Math.max(0.05, Math.min((r.width - 16) / imgW, (r.height - 16) / imgH));
    canvas.style.width = `${Math.floor(imgW * s)}px`;
    canvas.style.height = `${Math.floor(imgH * s)}px`;
    canvas.classList.toggle("pixelated", s >= 2);
  }
  window.addEventListener("resize", fitCanvas);

  // ------------------------------------------------------------------ stats + plan
  const fmtNum = (x, d = 1) => (x === null || x === undefined ? "–" : Number(x).toFixed(d));
  function fmtRate(x) {
    if (!x) return "0";
    const u = [["G", 1e9], ["M", 1e6], ["k", 1e3]].find(([, v]) => x >= v);
    return u ? `${(x / u[1]).toFixed(2)} ${u[0]}` : x.toFixed(0);
  }
  function esc(s) { return String(s).replace(/[&<>"']/g, (c) => `&#${c.charCodeAt(0)};`); }
  const fmtErr = (x) => (x === null || x === undefined ? "–" : Number(x).toExponential(2));
  // DOM built with nodes and CSSOM (element.style), never style="" markup: the page's CSP
  // (style-src 'self') refuses inline style attributes.
  function el(tag, cls, text) {
    const e = document.createElement(tag);
    if (cls) e.className = cls;
    if (text !== undefined) e.textContent = text;
    return e;
  }
  function lines(box, texts, cls) {
    box.textContent = "";
    for (const t of texts) box.appendChild(el("div", cls, t));
  }
  // time-vs-error history since the accumulation last restarted
  const history = { gen: null, t0: 0, points: [] };
  function record(s) {
    const now = performance.now() / 1000;
    const last = history.points[history.points.length - 1];
    if (history.gen !== dbg.generation || (last && s.accumulated < last.acc)) {
      history.gen = dbg.generation; history.t0 = now; history.points = [];
    }
    if (s.noise_estimate !== null || s.true_rel_mse !== null) {
      history.points.push({ t: now - history.t0, acc: s.accumulated, noise: s.noise_estimate, truth: s.true_rel_mse });
      if (history.points.length > 600) history.points.splice(0, history.points.length - 600);
    }
  }
  function drawPlot() {
    const cv = $("error-plot");
    const g = cv.getContext("2d");
    const W = cv.width, H = cv.height, L = 34, B = 14;
    g.clearRect(0, 0, W, H);
    g.font = "9px monospace"; g.fillStyle = "#9aa2ab"; g.strokeStyle = "#555";
    g.strokeRect(L, 2, W - L - 2, H - B - 2);
    const pts = history.points;
    const vals = [];
    for (const p of pts) for (const v of [p.noise, p.truth]) if (v > 0) vals.push(Math.log10(v));
    if (!pts.length || !vals.length) { g.fillText("error: waiting for frames", L + 4, H / 2); return; }
    let lo = Math.floor(Math.min(...vals)), hi = Math.ceil(Math.max(...vals));
    if (hi <= lo) hi = lo + 1;
    const tmax = Math.max(1, pts[pts.length - 1].t);
    const x = (t) => L + (t / tmax) * (W - L - 4);
    const y = (v) => 2 + (1 - (Math.log10(v) - lo) / (hi - lo)) * (H - B - 4);
    g.fillText(`1e${hi}`, 2, 10); g.fillText(`1e${lo}`, 2, H - B);
    g.fillText("0", L, H - 3); g.fillText(`${tmax.toFixed(0)} s`, W - 30, H - 3);
    for (const [key, color] of [["noise", "#f0b429"], ["truth", "#6cb6ff"]]) {
      g.strokeStyle = color; g.lineWidth = 1.5; g.beginPath();
      let on = false;
      for (const p of pts) {
        const v = p[key];
        if (!(v > 0)) { on = false; continue; }
        if (on) g.lineTo(x(p.t), y(v)); else { g.moveTo(x(p.t), y(v)); on = true; }
      }
      g.stroke();
    }
  }
  function onStats(s) {
    dbg.stats = s;
    const noise = s.noise_estimate !== undefined ? s.noise_estimate : s.relative_error;
    s.noise_estimate = noise;
    const text = [
      `${fmtNum(s.fps, 2)} fps · ${s.accumulated} accumulated`,
      `${fmtRate(s.rays_per_s)}rays/s`,
      `noise estimate ${fmtErr(noise)} (relMSE from even/odd frames; blind to bias)`,
    ];
    if (s.reference) {
      text.push(s.true_rel_mse === null || s.true_rel_mse === undefined
        ? `true relMSE – (view or scene differs from ${s.reference})`
        : `true relMSE ${fmtErr(s.true_rel_mse)} vs ${s.reference}`);
    }
    text.push(`input→frame ${fmtNum(s.view_latency_ms, 0)} ms · ${s.width}×${s.height}`,
              `workers ${s.workers} (${s.threads} threads) · scene v${s.scene_version}`);
    lines($("stats-text"), text);
    const box = $("stats-workers");
    box.textContent = "";
    for (const w of s.per_worker || []) {
      const pct = Math.round(100 * Math.min(1, Math.max(0, w.busy || 0)));
      const row = el("div", "worker");
      const track = el("span", "track");
      const bar = el("span", "bar");
      bar.style.width = `${Math.max(pct, 1)}%`;  // CSSOM: allowed by the CSP
      track.appendChild(bar);
      row.appendChild(track);
      row.appendChild(document.createTextNode(
        `${w.name}@${w.host} busy ${pct}% load ${Math.round(100 * (w.load || 0))}%`));
      box.appendChild(row);
    }
    const left = (s.workers_left || []).slice(-3).map((d) => `${d.name} left: ${d.reason}`);
    lines($("stats-left"), left);
    record(s);
    drawPlot();
    if (s.plan) showPlan(s.plan);
  }
  function showPlan(plan) {
    $("plan").innerHTML = plan.lines.map((l) => (l.startsWith("ON") ? `<span class="on">${esc(l)}</span>` : esc(l))).join("\n");
  }

  // ------------------------------------------------------------------ parameter panel (from the schema)
  const controls = {};
  let inUse = {};
  const SLIDER_STEPS = 1000;
  // Slider position <-> value. Position 0 is the -1 sentinel ("auto", "unlimited", ...) where
  // the parameter has one; a "log" scale spreads ranges that span decades (log1p for integers
  // from 0, log over [max·1e-5, max] for fractions), so e.g. 4 of 0…256 VPLs sits near 30 %.
  function sliderScale(p) {
    const isInt = p.type === "int";
    const special = p.special !== null && p.special !== undefined && p.min === -1;
    const lo = special ? (isInt ? 1 : 0) : p.min, hi = p.max;
    const start = special ? 1 : 0, span = SLIDER_STEPS - start;
    let fwd, inv;
    if (p.scale === "log" && isInt) {
      const L = Math.log1p(hi - lo);
      fwd = (v) => Math.log1p(Math.max(0, v - lo)) / L;
      inv = (t) => lo + Math.round(Math.expm1(t * L));
    } else if (p.scale === "log") {
      const eps = hi * 1e-5, L = Math.log(hi / eps);
      fwd = (v) => (v <= eps ? 0 : Math.log(v / eps) / L);
      inv = (t) => (t <= 0 ? 0 : Number((eps * Math.exp(t * L)).toPrecision(3)));
    } else {
      fwd = (v) => (v - lo) / (hi - lo);
      inv = (t) => (isInt ? Math.round(lo + t * (hi - lo)) : Number((lo + t * (hi - lo)).toPrecision(3)));
    }
    const clamp01 = (t) => Math.min(1, Math.max(0, t));
    return {
      toPos: (v) => (special && v === -1 ? 0 : start + Math.round(clamp01(fwd(v)) * span)),
      fromPos: (pos) => (special && pos === 0 ? -1 : inv((pos - start) / span)),
    };
  }
  function showValue(p, v) {
    if (p.special && v === -1) {
      const u = inUse[p.name];
      return u === undefined || u === p.special ? p.special : `${p.special} (= ${u})`;
    }
    return p.type === "int" ? String(v) : String(Number(Number(v).toPrecision(4)));
  }
  function parseValue(p, text) {
    const t = String(text).trim().toLowerCase();
    if (p.special && (t === "-1" || t.startsWith(p.special) || t.startsWith("auto"))) return -1;
    const v = Number(t);
    return Number.isFinite(v) ? v : null;
  }
  function buildPanel(params) {
    const form = $("params");
    form.textContent = "";
    const groups = {};
    for (const p of schema) {
      if (!groups[p.group]) {
        const fs = document.createElement("fieldset");
        const lg = document.createElement("legend");
        lg.textContent = p.group;
        fs.appendChild(lg);
        form.appendChild(fs);
        groups[p.group] = fs;
      }
      const row = document.createElement("div");
      row.className = "param" + (p.type === "bool" ? " bool" : "");
      row.title = p.help;
      const label = document.createElement("label");
      label.textContent = p.name.replace(/_/g, " ");
      label.htmlFor = `p-${p.name}`;
      row.appendChild(label);
      const value = params ? params[p.name] : p.default;
      if (p.type === "bool") {
        const cb = document.createElement("input");
        cb.type = "checkbox"; cb.id = `p-${p.name}`; cb.dataset.param = p.name; cb.checked = !!value;
        cb.addEventListener("change", () => sendParam(p, cb.checked));
        row.appendChild(cb);
        controls[p.name] = { set: (v) => { cb.checked = !!v; } };
      } else {
        const num = document.createElement("input");
        num.type = "text"; num.className = "val"; num.dataset.param = p.name;
        num.setAttribute("inputmode", "decimal");
        let slider = null;
        const scale = p.min !== null && p.max !== null ? sliderScale(p) : null;
        if (scale) {
          slider = document.createElement("input");
          slider.type = "range"; slider.id = `p-${p.name}`; slider.dataset.param = p.name;
          slider.min = "0"; slider.max = String(SLIDER_STEPS); slider.step = "1";
          slider.dataset.scale = p.scale || "linear";
          let deb = null;
          slider.addEventListener("input", () => {
            const v = scale.fromPos(Number(slider.value));
            num.value = showValue(p, v);
            clearTimeout(deb);
            deb = setTimeout(() => sendParam(p, v), 200);
          });
          slider.addEventListener("change", () => { clearTimeout(deb); sendParam(p, scale.fromPos(Number(slider.value))); });
          row.appendChild(slider);
        } else {
          num.id = `p-${p.name}`;
          row.appendChild(document.createElement("span"));
        }
        num.addEventListener("change", () => {
          const v = parseValue(p, num.value);
          if (v !== null) sendParam(p, v);
          else say(`${p.name}: not a number`, false);
        });
        row.appendChild(num);
        const set = (v) => {
          num.value = showValue(p, v);
          num.classList.toggle("auto", p.special !== null && p.special !== undefined && v === -1);
          if (slider) slider.value = String(scale.toPos(v));
        };
        set(value);
        controls[p.name] = { set };
      }
      groups[p.group].appendChild(row);
    }
  }
  let lastSent = {};
  function sendParam(p, v) {
    if (lastSent[p.name] === v) return;
    lastSent[p.name] = v;
    send({ type: "params", values: { [p.name]: v } });
  }
  function showParams(params) {
    dbg.params = params;
    lastSent = {};
    for (const [k, v] of Object.entries(params || {})) {
      if (controls[k]) { controls[k].set(v); lastSent[k] = v; }
    }
  }

  // ------------------------------------------------------------------ selection + moves
  function fillObjects() {
    const sel = $("objects");
    sel.textContent = "";
    const none = new Option("— none —", "");
    sel.appendChild(none);
    for (const m of scene.meshes) sel.appendChild(new Option(`${m.name}${m.emitter >= 0 ? " (light)" : ""}`, `m${m.index}`));
    for (const e of scene.emitters) {
      if (e.kind === "point" || e.kind === "spot") sel.appendChild(new Option(`${e.name} (${e.kind} light)`, `e${e.index}`));
    }
  }
  function showSelection(s) {
    dbg.selection = s;
    const badge = $("selection-badge");
    if (!s) {
      $("selection").textContent = "nothing selected — click the image";
      badge.hidden = true;
      $("objects").value = "";
      return;
    }
    const what = s.kind === "light" ? "light" : "object";
    $("selection").textContent = `${what} “${s.name}” at (${s.point.map((x) => x.toFixed(2)).join(", ")}) — ` +
      "ctrl/alt-drag or arrow keys (PgUp/PgDn: depth) to move, Esc to deselect";
    badge.textContent = `selected: ${s.name}`;
    badge.hidden = false;
    $("objects").value = s.mesh !== null && s.mesh !== undefined ? `m${s.mesh}` : `e${s.emitter}`;
  }
  $("objects").addEventListener("change", (ev) => {
    const v = ev.target.value;
    if (!v) send({ type: "deselect" });
    else if (v[0] === "m") send({ type: "select", mesh: Number(v.slice(1)) });
    else send({ type: "select", emitter: Number(v.slice(1)) });
  });
  let pendingMove = [0, 0, 0], moveInFlight = false;
  function queueMove(delta) {
    if (!dbg.selection) { say("select an object first (click it)"); return; }
    pendingMove = add(pendingMove, delta);
    flushMove();
  }
  function flushMove() {
    if (moveInFlight || len(pendingMove) === 0) return;
    moveInFlight = true;
    dbg.movesSent++;
    send({ type: "move", delta: pendingMove });
    pendingMove = [0, 0, 0];
  }
  function selectionDistance() {
    const s = dbg.selection;
    return s ? Math.max(len(sub(s.point, cam.origin)), diag() * 0.01) : dist();
  }

  // ------------------------------------------------------------------ mouse + keyboard
  function imagePixel(ev) {
    const r = canvas.getBoundingClientRect();
    return [((ev.clientX - r.left) / r.width) * imgW, ((ev.clientY - r.top) / r.height) * imgH];
  }
  let drag = null;
  canvas.addEventListener("contextmenu", (ev) => ev.preventDefault());
  canvas.addEventListener("mousedown", (ev) => {
    ev.preventDefault();
    stage.focus();
    let mode = "orbit";
    if (ev.button === 1 || ev.button === 2 || ev.shiftKey) mode = "pan";
    if (ev.button === 0 && (ev.ctrlKey || ev.altKey || ev.metaKey)) mode = "move";
    drag = { mode, x: ev.clientX, y: ev.clientY, x0: ev.clientX, y0: ev.clientY, moved: false, button: ev.button };
    canvas.classList.add("dragging");
  });
  window.addEventListener("mousemove", (ev) => {
    if (!drag) return;
    const dx = ev.clientX - drag.x, dy = ev.clientY - drag.y;
    drag.x = ev.clientX; drag.y = ev.clientY;
    if (Math.abs(ev.clientX - drag.x0) + Math.abs(ev.clientY - drag.y0) > 3) drag.moved = true;
    if (!drag.moved || (dx === 0 && dy === 0)) return;
    if (drag.mode === "orbit") orbit(dx, dy);
    else if (drag.mode === "pan") pan(dx, dy);
    else {
      const s = pixelWorld(selectionDistance());
      queueMove(add(mul(cam.left, -dx * s), mul(cam.up, -dy * s)));
    }
  });
  window.addEventListener("mouseup", (ev) => {
    if (!drag) return;
    const d = drag;
    drag = null;
    canvas.classList.remove("dragging");
    if (!d.moved && d.button === 0 && d.mode === "orbit") {
      const [x, y] = imagePixel(ev);
      send({ type: "select", x, y });
    }
  });
  canvas.addEventListener("wheel", (ev) => {
    ev.preventDefault();
    const unit = ev.deltaMode === 1 ? 33 : ev.deltaMode === 2 ? 400 : 1;
    zoom((ev.deltaY * unit) / 100);
  }, { passive: false });

  const keys = new Set();
  let flyLast = 0, flyRaf = 0;
  const FLY = { KeyW: [0, 0, 1], KeyS: [0, 0, -1], KeyA: [1, 0, 0], KeyD: [-1, 0, 0], KeyE: [0, 1, 0], KeyQ: [0, -1, 0] };
  function flyStep(t) {
    const dt = flyLast ? Math.min(0.1, (t - flyLast) / 1000) : 1 / 60;
    flyLast = t;
    let v = [0, 0, 0];
    for (const k of keys) {
      const f = FLY[k];
      if (f) v = add(v, add(add(mul(cam.left, f[0]), mul(cam.worldUp, f[1])), mul(cam.fwd, f[2])));
    }
    if (len(v) > 0) fly(mul(norm(v), diag() * 0.35 * dt * (keys.has("ShiftLeft") || keys.has("ShiftRight") ? 4 : 1)));
    if ([...keys].some((k) => FLY[k])) flyRaf = requestAnimationFrame(flyStep);
    else { flyRaf = 0; flyLast = 0; }
  }
  function typing(ev) {
    const t = ev.target;
    return t && (t.tagName === "INPUT" || t.tagName === "SELECT" || t.tagName === "TEXTAREA");
  }
  window.addEventListener("keydown", (ev) => {
    if (typing(ev) || ev.ctrlKey || ev.metaKey) return;
    keys.add(ev.code);
    if (FLY[ev.code]) {
      ev.preventDefault();
      if (!flyRaf) flyRaf = requestAnimationFrame(flyStep);
      return;
    }
    const step = diag() * 0.02 * (ev.shiftKey ? 5 : 1);
    const moves = { ArrowLeft: mul(cam.left, step), ArrowRight: mul(cam.left, -step), ArrowUp: mul(cam.up, step),
                    ArrowDown: mul(cam.up, -step), PageUp: mul(cam.fwd, step), PageDown: mul(cam.fwd, -step) };
    if (moves[ev.code] && dbg.selection) { ev.preventDefault(); queueMove(moves[ev.code]); }
    else if (ev.code === "Escape") send({ type: "deselect" });
    else if (ev.code === "KeyR") send({ type: "reset" });
  });
  window.addEventListener("keyup", (ev) => keys.delete(ev.code));
  window.addEventListener("blur", () => keys.clear());

  // ------------------------------------------------------------------ view controls
  $("exposure").addEventListener("input", () => {
    $("exposure-out").textContent = Number($("exposure").value).toFixed(1);
    send({ type: "settings", exposure: Number($("exposure").value) });
  });
  $("format").addEventListener("change", () => send({ type: "settings", format: $("format").value }));
  $("reset").addEventListener("click", () => send({ type: "reset" }));
  $("res-apply").addEventListener("click", () => {
    send({ type: "resolution", width: Number($("res-w").value), height: Number($("res-h").value) });
  });
  $("save-png").href = withToken("save.png");
  $("save-exr").href = withToken("save.exr");

  // ------------------------------------------------------------------ the socket
  function onJSON(m) {
    switch (m.type) {
      case "init":
        schema = m.schema; scene = m.scene; dbg.version = m.scene_version; inUse = m.in_use || {};
        cam.ready = false;
        setCamera(m.view.camera, m.view.fov_x);
        $("res-w").value = m.view.width; $("res-h").value = m.view.height;
        buildPanel(m.params); showParams(m.params); fillObjects(); showSelection(null);
        if (m.plan) showPlan(m.plan);
        break;
      case "stats": onStats(m); break;
      case "params": inUse = m.in_use || inUse; showParams(m.params); say("parameters applied"); break;
      case "view":
        $("res-w").value = m.view.width; $("res-h").value = m.view.height;
        break;
      case "selected":
        showSelection(m.selection);
        if (!m.selection) say("nothing there");
        break;
      case "moved":
        moveInFlight = false; dbg.version = m.version;
        if (dbg.selection) showSelection(m.selection);
        flushMove();
        break;
      case "error":
        if (m.request === "move") { moveInFlight = false; pendingMove = [0, 0, 0]; }
        if (m.request === "params" && dbg.params) showParams(dbg.params);
        say(m.message, true);
        break;
      default: break;
    }
  }
  function connect() {
    const url = new URL(withToken("ws"), location.href);
    url.protocol = location.protocol === "https:" ? "wss:" : "ws:";
    ws = new WebSocket(url);
    ws.binaryType = "arraybuffer";
    ws.onopen = () => {
      dbg.connected = true;
      $("conn").textContent = "live"; $("conn").className = "conn on";
      if ($("format").value !== "jpeg" || Number($("exposure").value) !== 0) {
        send({ type: "settings", format: $("format").value, exposure: Number($("exposure").value) });
      }
    };
    ws.onmessage = (ev) => (typeof ev.data === "string" ? onJSON(JSON.parse(ev.data)) : onFrame(ev.data));
    ws.onclose = () => {
      dbg.connected = false; moveInFlight = false;
      $("conn").textContent = "disconnected – retrying"; $("conn").className = "conn off";
      setTimeout(connect, 1000);
    };
  }
  connect();
})();
