// uwsimnet view: one page for a replayed trace and a live world (docs/view.md).
// The document and updates are described in uwsimnet_zenoh/view/state.py.  No build step, no libraries.
"use strict";

(function () {
  const HOLD = 1.5;          // s of simulation time an outcome stays drawn at its receiver
  const TRAIL = 60;          // s of trail behind each vehicle
  const LIST = 40;           // frames in the list (the latest that pass the filters)
  const DISC = 8;            // px radius of a vehicle's disc
  const CAP = { frames: 4000, events: 5000, poses: 3000 };
  const COLORS = { rx: "#2ecc71", col: "#e74c3c", prop: "#b0b0b0", mult: "#ff8c1a", range: "#7f8c8d" };
  const $ = (id) => document.getElementById(id);
  const { LINK_WINDOW, lastAtOrBefore, el, perColor, perAt, seriesAt, LinkStats } = window.uwsimnetLib;

  const S = {
    doc: null, mode: "replay", T: 0, playing: false, speed: 1, follow: true, ready: false,
    framesById: new Map(), frames: [], evByDev: new Map(), evAll: [], evIdx: -1, links: null, maxDelay: 1,
    bounds: null, zr: [0, 1], circle: new Map(), lastWall: null, clockAt: 0, connected: false, updates: 0,
    sel: null, linkBy: null, labelBoxes: {},
  };

  // -- helpers -----------------------------------------------------------------------------------
  function depthColor(z) {
    const [lo, hi] = S.zr;
    const f = hi > lo ? (hi - z) / (hi - lo) : 0.5;  // z up: the highest (shallowest) light, the lowest dark
    const stops = [[246, 246, 122], [55, 200, 200], [42, 62, 168]];
    const g = Math.max(0, Math.min(1, f)) * 2, i = Math.min(1, Math.floor(g)), k = g - i;
    return `rgb(${stops[i].map((x, j) => Math.round(x + (stops[i + 1][j] - x) * k)).join(",")})`;
  }
  // -- the document --------------------------------------------------------------------------------
  function addFrame(f) {
    const old = S.framesById.get(f.id);
    const seen = old ? old.outcomes : {};
    if (old) { old.outcomes = f.outcomes; } else {
      S.framesById.set(f.id, f);
      S.frames.push(f);
      if (S.frames.length > CAP.frames && S.mode === "live") S.framesById.delete(S.frames.shift().id);
    }
    for (const [rid, o] of Object.entries(f.outcomes)) {
      S.maxDelay = Math.max(S.maxDelay, o.t - f.t);
      if (!seen[rid]) { if (S.pending) S.pending.push([f.dev, rid, o]); else S.links.add(f.dev, rid, o); }
    }
  }
  function addEvent(e) {
    let a = S.evByDev.get(e[1]);
    if (!a) { a = []; S.evByDev.set(e[1], a); }
    a.push(e);
    S.evAll.push(e);
    if (S.mode === "live") {
      if (a.length > CAP.events) a.shift();
      if (S.evAll.length > CAP.events) { S.evAll.shift(); S.evIdx--; }
    }
  }
  function load(doc) {
    S.doc = doc; S.mode = doc.mode;
    S.framesById = new Map(); S.frames = []; S.evByDev = new Map(); S.evAll = []; S.evIdx = -1;
    S.links = new LinkStats(doc.mode === "live" ? CAP.events : 0);
    S.maxDelay = 1; S.pending = [];
    for (const f of doc.frames) addFrame(f);
    for (const [tx, rx, o] of S.pending.sort((a, b) => a[2].t - b[2].t)) S.links.add(tx, rx, o);
    S.pending = null;
    for (const e of doc.events) addEvent(e);
    fitBounds();
    $("title").textContent = doc.title;
    $("mode").textContent = doc.mode === "live" ? "live" : "replay";
    $("replaybar").hidden = doc.mode === "live";
    $("livebar").hidden = doc.mode !== "live";
    $("nopos").hidden = !!doc.positions;
    if (doc.mode === "live") setClock(doc.clock); else { S.T = doc.t0; }
    ctlButtons();
    buildModems();
    linkMode();
    S.ready = true;
  }
  function fitBounds() {
    let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity, z0 = Infinity, z1 = -Infinity;
    for (const samples of Object.values(S.doc.poses)) {
      for (const s of samples) {
        x0 = Math.min(x0, s[1]); x1 = Math.max(x1, s[1]); y0 = Math.min(y0, s[2]); y1 = Math.max(y1, s[2]);
        z0 = Math.min(z0, s[3]); z1 = Math.max(z1, s[3]);
      }
    }
    if (!isFinite(x0)) { x0 = -1; y0 = -1; x1 = 1; y1 = 1; z0 = 0; z1 = 1; }
    const pad = Math.max(x1 - x0, y1 - y0, 2) * 0.12;
    S.bounds = [x0 - pad, y0 - pad, x1 + pad, y1 + pad];
    S.zr = [z0, z1];
    $("zrange").textContent = isFinite(z0) ? `${z0.toFixed(1)} … ${z1.toFixed(1)}` : "";
    const names = Object.keys(S.doc.vehicles).sort();
    names.forEach((v, i) => {                       // the circle for vehicles without any position
      const a = 2 * Math.PI * i / Math.max(1, names.length);
      S.circle.set(v, [Math.cos(a), Math.sin(a), 0]);
    });
  }
  function grow(p) {                                  // live: widen the map when a vehicle leaves it
    const b = S.bounds;
    if (p[0] < b[0] || p[0] > b[2] || p[1] < b[1] || p[1] > b[3]) {
      const w = Math.max(b[2] - b[0], b[3] - b[1]) * 0.1;
      S.bounds = [Math.min(b[0], p[0] - w), Math.min(b[1], p[1] - w), Math.max(b[2], p[0] + w), Math.max(b[3], p[1] + w)];
    }
    if (p[2] < S.zr[0] || p[2] > S.zr[1]) S.zr = [Math.min(S.zr[0], p[2]), Math.max(S.zr[1], p[2])];
  }
  function apply(u) {
    S.updates++;
    const d = S.doc;
    if (u.type === "event") addEvent(u.e);
    else if (u.type === "frame") addFrame(u.f);
    else if (u.type === "pose") {
      const a = d.poses[u.vehicle] || (d.poses[u.vehicle] = []);
      a.push(u.s);
      if (a.length > CAP.poses) a.shift();
      if (!d.vehicles[u.vehicle]) d.vehicles[u.vehicle] = { source: "zenoh" };
      if (a.length === 1 && Object.values(d.poses).reduce((n, x) => n + x.length, 0) === 1) fitBounds();
      grow(u.s.slice(1));
    } else if (u.type === "clock") setClock(u.clock);
    else if (u.type === "control") { d.control = u.control; ctlButtons(); }
    else if (u.type === "kind") { if (d.devices[u.dev]) d.devices[u.dev].kind = u.kind; buildModems(); }
    else if (u.type === "link") {                   // a live sample of a geometry model's link (HIL)
      const dev = d.devices[u.dev];
      if (dev) {
        const L = dev.links || (dev.links = {}), a = L[u.rx] || (L[u.rx] = []);
        a.push(u.s);
        if (a.length > CAP.poses) a.shift();
      }
    } else if (u.type === "devices") {
      for (const [k, v] of Object.entries(u.devices)) if (d.devices[k] && d.devices[k].links) v.links = d.devices[k].links;
      d.devices = u.devices;
      for (const [k, v] of Object.entries(u.vehicles)) if (!d.vehicles[k]) d.vehicles[k] = v;
      for (const k of Object.keys(u.vehicles)) if (!d.poses[k]) d.poses[k] = [];
      buildModems();
    }
  }
  function setClock(c) {
    S.doc.clock = c;
    S.clockAt = performance.now() / 1000;
    $("paused").hidden = !c.paused;
  }
  function liveNow() {                               // simulation time now, from the last clock sample
    const c = S.doc.clock;
    if (!c || c.paused) return c ? c.t : 0;
    return c.t + (performance.now() / 1000 - S.clockAt) * (c.speed || 1);
  }

  // -- state at time T -----------------------------------------------------------------------------
  function posAt(v, T) {
    const a = S.doc.poses[v];
    if (!S.doc.positions) return S.circle.get(v) || [0, 0, 0];
    if (!a || !a.length) return null;
    const i = lastAtOrBefore(a, T, (s) => s[0]);
    if (i < 0) return a[0].slice(1);
    if (i === a.length - 1) return a[i].slice(1);
    const s0 = a[i], s1 = a[i + 1], f = s1[0] > s0[0] ? (T - s0[0]) / (s1[0] - s0[0]) : 0;
    return [1, 2, 3].map((k) => s0[k] + (s1[k] - s0[k]) * f);
  }
  function devPos(dev, T) {
    const d = S.doc.devices[dev];
    return d && d.vehicle != null ? posAt(d.vehicle, T) : null;
  }
  function devState(dev, T) {
    const a = S.evByDev.get(dev) || [];
    const i = lastAtOrBefore(a, T, (e) => e[0]);
    if (i < 0) return { enq: 0, tx: 0, rx: 0, drop: 0, fifo: 0 };
    const e = a[i];
    return { enq: e[5], tx: e[6], rx: e[7], drop: e[8], fifo: e[4] || 0 };
  }
  function framesNear(T) {                           // frames transmitted in [T - lookback, T]
    const i = lastAtOrBefore(S.frames, T, (f) => f.t);
    const out = [];
    const from = T - S.maxDelay - HOLD;
    for (let k = i; k >= 0 && S.frames[k].t >= from; k--) out.push(S.frames[k]);
    return out;
  }
  function expected(f) {                            // receivers that will trace an outcome of this frame
    const n = Object.keys(f.outcomes).length;
    if (S.mode !== "live") return n;                 // a replayed trace is complete: what it has is all
    if (f.dst !== 255) return 1;                     // unicast: its addressee only
    const others = Object.entries(S.doc.devices).filter(([id, d]) => id !== f.dev && d.rx_channel === f.ch).length;
    return Math.max(others, n);
  }
  function frameStatus(f, T) {                      // {state: air|done, outcomes at T}
    const outs = Object.entries(f.outcomes).filter(([, o]) => o.t <= T).map(([dev, o]) => [dev, o.outcome]);
    const n = expected(f);
    const last = Math.max(f.t, ...Object.values(f.outcomes).map((o) => o.t));
    const state = n > 0 && outs.length >= n ? "done"
      : (S.mode === "live" && outs.length > 0 && T > last + 10 * S.maxDelay + HOLD) ? "done" : "air";
    return { state, outs };
  }

  // -- drawing -------------------------------------------------------------------------------------
  const canvas = $("map"), ctx = canvas.getContext("2d");
  const V = { zoom: 1, dx: 0, dy: 0 };               // the user's zoom and pan (px) over the fitted map
  function scale() {
    const [x0, y0, x1, y1] = S.bounds;
    return Math.min(canvas.width / (x1 - x0), canvas.height / (y1 - y0)) * V.zoom;
  }
  function toPx(p) {                                   // fitted and centred, then zoomed about the centre and panned
    const [x0, y0, x1, y1] = S.bounds, W = canvas.width, H = canvas.height, s = scale();
    const cx = (x0 + x1) / 2, cy = (y0 + y1) / 2;
    return [W / 2 + V.dx + (p[0] - cx) * s, H / 2 + V.dy - (p[1] - cy) * s];
  }
  function zoomAt(f, px, py) {                         // zoom by f keeping the map point under (px, py) still
    const nz = Math.max(0.05, Math.min(1e4, V.zoom * f)), k = nz / V.zoom;
    const W = canvas.width / 2, H = canvas.height / 2;
    V.dx = (px - W) - (px - W - V.dx) * k; V.dy = (py - H) - (py - H - V.dy) * k; V.zoom = nz;
  }
  function drawGrid() {                               // metric axes only where positions are real (--scene)
    if (!S.doc.positions) return;
    const W = canvas.width, H = canvas.height, s = scale(), [cx, cy] = [(S.bounds[0] + S.bounds[2]) / 2, (S.bounds[1] + S.bounds[3]) / 2];
    const x0 = cx - (W / 2 + V.dx) / s, x1 = cx + (W / 2 - V.dx) / s, y0 = cy - (H / 2 - V.dy) / s, y1 = cy + (H / 2 + V.dy) / s;
    const span = Math.max(x1 - x0, y1 - y0);
    const step = Math.pow(10, Math.floor(Math.log10(span / 4)));
    ctx.strokeStyle = "#1a3350"; ctx.lineWidth = 1; ctx.fillStyle = "#4f6f8f"; ctx.font = "10px sans-serif";
    for (let x = Math.ceil(x0 / step) * step; x <= x1; x += step) {
      const [px] = toPx([x, y0]); ctx.beginPath(); ctx.moveTo(px, 0); ctx.lineTo(px, canvas.height); ctx.stroke();
      ctx.fillText(`${+x.toFixed(6)}`, px + 2, canvas.height - 3);
    }
    for (let y = Math.ceil(y0 / step) * step; y <= y1; y += step) {
      const [, py] = toPx([x0, y]); ctx.beginPath(); ctx.moveTo(0, py); ctx.lineTo(canvas.width, py); ctx.stroke();
      ctx.fillText(`${+y.toFixed(6)}`, 2, py - 2);
    }
    ctx.fillText(`grid ${step} m (x right, y up)`, canvas.width - 130, 12);
  }
  function drawLinks(T) {
    const devs = S.doc.devices;
    S.drawn = [];                                   // [tx, rx, from px, to px]: what a click may hit
    for (const [id, d] of Object.entries(devs)) {
      const p = devPos(id, T);
      if (!p) continue;
      for (const [rid, r] of Object.entries(devs)) {
        if (rid === id || r.rx_channel !== d.tx_channel || r.vehicle === d.vehicle) continue;
        const q = devPos(rid, T);
        if (!q) continue;
        const dist = Math.hypot(p[0] - q[0], p[1] - q[1], p[2] - q[2]);
        if (dist < (d.min_distance || 0) || (d.max_distance != null && dist > d.max_distance)) continue;
        const per = linkLoss(id, rid, d, dist, T);
        const a = toPx(p), b = toPx(q);
        const len = Math.hypot(b[0] - a[0], b[1] - a[1]) || 1, nx = -(b[1] - a[1]) / len * 2, ny = (b[0] - a[0]) / len * 2;
        ctx.strokeStyle = per == null ? "#5d6d7e" : perColor(per);
        ctx.globalAlpha = 0.75; ctx.lineWidth = 2; ctx.setLineDash(per == null ? [4, 4] : []);
        const sel = S.sel && S.sel.link && S.sel.link[0] === id && S.sel.link[1] === rid;
        ctx.globalAlpha = sel ? 1 : 0.75; ctx.lineWidth = sel ? 4 : 2;
        ctx.beginPath(); ctx.moveTo(a[0] + nx, a[1] + ny); ctx.lineTo(b[0] + nx, b[1] + ny); ctx.stroke();
        ctx.setLineDash([]); ctx.globalAlpha = 1;
        S.drawn.push([id, rid, [a[0] + nx, a[1] + ny], [b[0] + nx, b[1] + ny]]);
      }
    }
  }
  function linkLoss(id, rid, d, dist, T) {          // the number a link is coloured by, or null (unknown)
    if (S.linkBy === "model") {
      if (!S.doc.positions) return null;
      const a = d.links && d.links[rid];             // a geometry model (Bellhop): asked along the scripted paths
      return a && a.length ? seriesAt(a, T) : perAt(d, dist);
    }
    const m = S.links.loss(id, rid, T);
    return m && m.loss;
  }
  function linkMode() {                             // modelled PER where the scene gives curves, else measured
    if (S.linkBy == null) {
      const curves = S.doc.positions && Object.values(S.doc.devices).some((d) => (d.per && d.per.length) ||
        d.links != null);
      S.linkBy = curves ? "model" : "measured";
    }
    $("linkby").value = S.linkBy;
    $("linkwhat").textContent = S.linkBy === "model"
      ? "PER modelled by the transmitter's channel model for a frame of the flows' size, at the link's distance" +
        " (or, for a geometry model such as Bellhop, at both ends' scripted positions)"
      : `measured loss, 1 − delivered / outcomes over the link's last ${LINK_WINDOW} frames up to the time shown`;
  }
  function drawVehicles(T) {
    const items = [];
    for (const v of Object.keys(S.doc.vehicles)) {
      const a = S.doc.poses[v] || [];
      if (S.doc.positions && a.length > 1) {          // trail
        ctx.strokeStyle = "rgba(160,200,240,0.35)"; ctx.lineWidth = 1.5; ctx.beginPath();
        let started = false;
        const i = lastAtOrBefore(a, T, (s) => s[0]);
        for (let k = Math.max(0, i); k >= 0 && a[k][0] >= T - TRAIL; k--) {
          const px = toPx(a[k].slice(1));
          if (!started) { const c = toPx(posAt(v, T)); ctx.moveTo(c[0], c[1]); started = true; }
          ctx.lineTo(px[0], px[1]);
        }
        if (i >= 0 && a[i][0] < T - TRAIL) { const px = toPx(posAt(v, T - TRAIL)); ctx.lineTo(px[0], px[1]); }
        ctx.stroke();
      }
      const p = posAt(v, T);
      if (!p) continue;
      const [x, y] = toPx(p);
      ctx.fillStyle = S.doc.positions ? depthColor(p[2]) : "#8fb3d9";
      ctx.strokeStyle = "#0a1320"; ctx.lineWidth = 2;
      ctx.beginPath(); ctx.arc(x, y, DISC, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
      if (S.sel && S.sel.vehicle === v) {
        ctx.strokeStyle = "#ffd27f"; ctx.lineWidth = 2;
        ctx.beginPath(); ctx.arc(x, y, DISC + 4, 0, 2 * Math.PI); ctx.stroke();
      }
      items.push({ key: v, x, y, text: S.doc.positions ? `${v} (z ${p[2].toFixed(1)})` : v });
    }
    drawLabels(items);
  }
  function drawLabels(items) {                      // SVG text over the map, placed apart (labels.js)
    ctx.font = "12px sans-serif";
    for (const it of items) { it.w = Math.ceil(ctx.measureText(it.text).width) + 8; it.h = 16; }
    const sig = items.map((it) => `${it.key} ${it.x.toFixed(1)} ${it.y.toFixed(1)} ${it.w}`).join("\n");
    const placed = sig === S.labelSig ? S.labelBoxes : window.uwsimnetLabels.place(items, DISC, canvas.width, canvas.height);
    S.labelSig = sig;                               // nothing moved: the same places (placing 256 labels takes ~15 ms)
    const svg = $("labels"), NS = "http://www.w3.org/2000/svg";
    const have = new Map([...svg.children].map((g) => [g.dataset.vehicle, g]));
    for (const it of items) {
      let g = have.get(it.key);
      if (!g) {
        g = document.createElementNS(NS, "g");
        g.setAttribute("class", "label");
        g.dataset.vehicle = it.key;
        g.append(document.createElementNS(NS, "line"), document.createElementNS(NS, "rect"),
          document.createElementNS(NS, "text"));
        g.addEventListener("click", () => select({ vehicle: g.dataset.vehicle }));
        svg.append(g);
      }
      have.delete(it.key);
      const { box: [bx, by, bw, bh], leader } = placed[it.key];
      const [ln, rc, tx] = g.children;
      for (const [k, val] of [["x", bx], ["y", by], ["width", bw], ["height", bh]]) rc.setAttribute(k, val.toFixed(1));
      tx.setAttribute("x", (bx + 4).toFixed(1)); tx.setAttribute("y", (by + 12).toFixed(1));
      if (tx.textContent !== it.text) tx.textContent = it.text;
      const ex = Math.max(bx, Math.min(it.x, bx + bw)), ey = Math.max(by, Math.min(it.y, by + bh));
      const len = Math.hypot(ex - it.x, ey - it.y) || 1, sx = it.x + (ex - it.x) / len * DISC, sy = it.y + (ey - it.y) / len * DISC;
      ln.setAttribute("visibility", leader ? "visible" : "hidden");
      for (const [k, val] of [["x1", sx], ["y1", sy], ["x2", ex], ["y2", ey]]) ln.setAttribute(k, val.toFixed(1));
      g.setAttribute("class", S.sel && S.sel.vehicle === it.key ? "label sel" : "label");
    }
    for (const g of have.values()) g.remove();
    S.labelBoxes = placed;
  }
  function drawFrames(T) {
    for (const f of framesNear(T)) {
      const p = devPos(f.dev, f.t);
      if (!p) continue;
      const a = toPx(p);
      const outs = Object.entries(f.outcomes);
      if (!outs.length && T - f.t < HOLD) {            // no outcome (yet): a ring around the sender
        ctx.strokeStyle = "#ffd27f"; ctx.lineWidth = 1.5;
        ctx.beginPath(); ctx.arc(a[0], a[1], 10 + 30 * (T - f.t) / HOLD, 0, 2 * Math.PI); ctx.stroke();
      }
      for (const [rid, o] of outs) {
        const q = devPos(rid, o.t);
        if (!q) continue;
        const b = toPx(q);
        const col = COLORS[o.outcome] || "#c77dff";
        if (T < o.t) {                                  // on its way: from the sender to the receiver
          const k = Math.max(0, Math.min(1, (T - f.t) / Math.max(1e-9, o.t - f.t)));
          const x = a[0] + (b[0] - a[0]) * k, y = a[1] + (b[1] - a[1]) * k;
          ctx.strokeStyle = "rgba(255,210,127,0.5)"; ctx.lineWidth = 1;
          ctx.beginPath(); ctx.moveTo(a[0], a[1]); ctx.lineTo(x, y); ctx.stroke();
          ctx.fillStyle = f.kind === "ctrl" ? "#ffffff" : "#ffd27f";
          ctx.beginPath(); ctx.arc(x, y, f.kind === "ctrl" ? 3 : 4.5, 0, 2 * Math.PI); ctx.fill();
        } else if (T < o.t + HOLD) {                    // its outcome, at the receiver
          ctx.strokeStyle = col; ctx.lineWidth = 2.5;
          ctx.beginPath(); ctx.arc(b[0], b[1], 13, 0, 2 * Math.PI); ctx.stroke();
          ctx.fillStyle = col; ctx.font = "bold 11px sans-serif"; ctx.fillText(o.outcome, b[0] - 8, b[1] + 25);
        }
      }
    }
  }
  function draw() {
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    drawGrid();
    drawLinks(S.T);
    drawVehicles(S.T);
    drawFrames(S.T);
  }

  // -- panels --------------------------------------------------------------------------------------
  function buildModems() {
    const tb = $("modems").tBodies[0];
    tb.replaceChildren();
    for (const [id, d] of Object.entries(S.doc.devices).sort()) {
      const tr = document.createElement("tr");
      tr.dataset.dev = id;
      tr.addEventListener("click", () => select({ dev: id }));
      const kind = d.kind == null ? "none" : d.kind;
      const badge = el("span", "badge " + (["sim", "real", "none"].includes(kind) ? kind : "other"), kind);
      tr.append(Object.assign(el("td", "", id), { title: `vehicle ${d.vehicle}` }), el("td", "kind", badge),
        el("td", "", d.address ?? ""), el("td", "", d.tx_channel ?? ""), el("td", "enq"), el("td", "tx"),
        el("td", "rx"), el("td", "drop"), el("td", "", el("span", "fifo", el("span")), " ", el("span", "fifob")));
      tb.appendChild(tr);
    }
    for (const [sel, vals] of [["fdev", Object.keys(S.doc.devices).sort()],
      ["fch", [...new Set(Object.values(S.doc.devices).map((d) => d.tx_channel).filter((c) => c != null).map(String))].sort()]]) {
      const cur = $(sel).value;
      $(sel).replaceChildren(el("option", "", "all"), ...vals.map((v) => el("option", "", v)));
      $(sel).options[0].value = ""; $(sel).value = vals.includes(cur) ? cur : "";
    }
    $("nveh").textContent = Object.keys(S.doc.vehicles).length;
    $("nmod").textContent = Object.keys(S.doc.devices).length;
  }
  function panels(T) {
    for (const tr of $("modems").tBodies[0].rows) {
      const dev = tr.dataset.dev, st = devState(dev, T), d = S.doc.devices[dev] || {};
      for (const k of ["enq", "tx", "rx", "drop"]) tr.querySelector("." + k).textContent = st[k];
      const cap = d.fifo_capacity;
      tr.querySelector(".fifo > span").style.width = cap ? `${Math.min(100, 100 * st.fifo / cap)}%` : "0%";
      tr.querySelector(".fifob").textContent = `${st.fifo} B`;
    }
    const items = [];
    const i = lastAtOrBefore(S.frames, T, (f) => f.t);
    const fl = { dev: $("fdev").value, ch: $("fch").value, kind: $("fkind").value, out: $("fout").value };
    for (let k = i; k >= 0 && items.length < LIST; k--) {
      const f = S.frames[k], st = frameStatus(f, T);
      if ((fl.dev && f.dev !== fl.dev && !st.outs.some(([d]) => d === fl.dev)) || (fl.ch && String(f.ch) !== fl.ch) ||
          (fl.kind && f.kind !== fl.kind) || (fl.out && (fl.out === "air" ? st.state !== "air" : !st.outs.some(([, o]) => o === fl.out)))) continue;
      const li = el("li", "", `${(+f.t).toFixed(3)} ${f.dev} → ${f.dst} #${f.seq}` +
        `${f.attempt > 1 && f.kind === "data" ? " (try " + f.attempt + ")" : ""} ${f.kind}${st.state === "air" ? " on air" : ""} `);
      Object.assign(li.dataset, { id: f.id, dev: f.dev, seq: f.seq, kind: f.kind, state: st.state,
        outcomes: st.outs.map(([dev, o]) => dev + "=" + o).join(" ") });
      st.outs.forEach(([dev, o], j) => li.append(j ? ", " : "", el("span", `o-${COLORS[o] ? o : "other"}`, `${dev} ${o}`)));
      items.push(li);
    }
    const cur = S.evIdx >= 0 && S.evAll[S.evIdx][0] === T ? eventFrame(S.evAll[S.evIdx]) : null;
    for (const li of items) if (cur && +li.dataset.id === cur.id) li.className = "cur";
    const sig = items.map((li) => li.textContent + li.dataset.state + li.className).join("\n");
    if (sig !== S.listSig) { S.listSig = sig; $("frames").replaceChildren(...items); }   // unchanged: clickable
    $("clock").textContent = `t = ${T.toFixed(3)} s`;
    if (S.evIdx >= 0 && S.evAll[S.evIdx][0] !== T) { S.evIdx = -1; $("stepinfo").textContent = ""; }
    for (const tr of $("modems").tBodies[0].rows) tr.className = S.sel && S.sel.devs.includes(tr.dataset.dev) ? "sel" : "";
    const moving = S.playing || (S.mode === "live" && S.follow);
    if (S.sel && (S.sel.T !== T || S.sel.n !== S.updates) && (!moving || !(performance.now() - S.sel.at < 250))) {
      S.sel.T = T; S.sel.n = S.updates; S.sel.at = performance.now();   // while time runs: 4 times a second
      $("detail").textContent = S.sel.link ? linkDetail(...S.sel.link, T)
        : S.sel.devs.map((dev) => modemDetail(dev, T)).join("\n\n") || `vehicle ${S.sel.vehicle}: no modem`;
    }
  }

  // -- a modem's details (a click on its vehicle, its label or its row) ----------------------------
  function select(sel) {
    if (sel.link) { S.sel = { link: sel.link, devs: [] }; return; }
    const devs = sel.dev != null ? [sel.dev]
      : Object.keys(S.doc.devices).filter((k) => S.doc.devices[k].vehicle === sel.vehicle).sort();
    S.sel = { vehicle: sel.vehicle ?? (S.doc.devices[sel.dev] || {}).vehicle, devs };
  }
  function linkDetail(tx, rx, T) {                 // a link: what colours it, from the model and from the trace
    const d = S.doc.devices[tx] || {}, p = devPos(tx, T), q = devPos(rx, T);
    const dist = p && q ? Math.hypot(p[0] - q[0], p[1] - q[1], p[2] - q[2]) : null;
    const series = d.links && d.links[rx], m = S.links.loss(tx, rx, T), outs = {};
    for (let k = lastAtOrBefore(S.frames, T, (f) => f.t); k >= 0; k--) {
      const f = S.frames[k], o = f.dev === tx && f.outcomes[rx];
      if (o && o.t <= T) outs[o.outcome] = (outs[o.outcome] || 0) + 1;
    }
    const fx = (v, n) => (v == null ? "unknown" : (+v).toFixed(n));
    const model = series && series.length ? `${fx(seriesAt(series, T), 3)} at both ends' positions` +
      (series.some((e) => e[2] != null) ? `, received level ${fx(seriesAt(series, T, 2), 1)} dB` : "")
      : dist != null && d.per ? `${fx(perAt(d, dist), 3)} at ${dist.toFixed(1)} m` : "unknown";
    return [`link ${tx} → ${rx} at t = ${T.toFixed(3)} s` + (dist != null && S.doc.positions ? `, ${dist.toFixed(1)} m` : ""),
      `  modelled PER (frame of ${d.link_size ?? "?"} B on air): ${model}`,
      `  measured loss: ` + (m ? `${fx(m.loss, 3)} (${m.got} of the last ${m.n} delivered)` : "no outcome yet"),
      `  outcomes up to t: ${Object.entries(outs).sort().map(([k, n]) => `${k} ${n}`).join(", ") || "none"}`].join("\n");
  }
  function modemDetail(dev, T) {                   // text only: every value is data, never markup (#41)
    const d = S.doc.devices[dev] || {}, st = devState(dev, T), p = d.vehicle != null ? posAt(d.vehicle, T) : null;
    const drops = {}, sent = { data: 0, ctrl: 0 }, outs = {}, heard = {};
    for (const e of S.evByDev.get(dev) || []) {
      if (e[0] > T) break;
      if (e[2] === "drop") drops[e[3]] = (drops[e[3]] || 0) + 1;
    }
    for (let k = lastAtOrBefore(S.frames, T, (f) => f.t); k >= 0; k--) {
      const f = S.frames[k];
      if (f.dev === dev) sent[f.kind] = (sent[f.kind] || 0) + 1;
      for (const [rid, o] of Object.entries(f.outcomes)) {
        if (o.t > T) continue;
        if (f.dev === dev) outs[o.outcome] = (outs[o.outcome] || 0) + 1;
        if (rid === dev) heard[o.outcome] = (heard[o.outcome] || 0) + 1;
      }
    }
    const list = (m) => Object.entries(m).sort().map(([k, n]) => `${k} ${n}`).join(", ") || "none";
    return [`modem ${dev} (${d.kind ?? "none"})`,
      `  address ${d.address ?? "?"} · vehicle ${d.vehicle ?? "?"} · MAC ${d.mac ?? "?"} · ${d.bitrate ?? "?"} bps` +
        ` · channel tx ${d.tx_channel ?? "?"} rx ${d.rx_channel ?? "?"}`,
      `  position at t = ${T.toFixed(3)} s: ` + (p && S.doc.positions ? `(${p.map((x) => x.toFixed(2)).join(", ")}) m` : "unknown"),
      `  trace up to t: enq ${st.enq}, tx ${st.tx}, rx ${st.rx}, drop ${st.drop}; FIFO ${st.fifo} B` +
        (d.fifo_capacity ? ` of ${d.fifo_capacity}` : ""),
      `  drops here by reason: ${list(drops)}`,
      `  frames sent: ${list(sent)}; their outcomes: ${list(outs)}`,
      `  frames heard, by outcome: ${list(heard)}`].join("\n");
  }

  // -- event stepping -------------------------------------------------------------------------------
  function eventFrame(e) {                          // the transmission an event row belongs to, or null
    const [t, dev, ev, , , , , , , src, seq, kind] = e;
    if (ev === "enq" || seq == null) return null;
    for (let k = lastAtOrBefore(S.frames, t, (f) => f.t); k >= 0; k--) {
      const f = S.frames[k];
      if (f.src === src && f.seq === seq && f.kind === kind && (ev === "tx" ? f.dev === dev && f.t === t : true)) return f;
      if (t - f.t > S.maxDelay + 1) break;
    }
    return null;
  }
  function step(dir) {
    const a = S.evAll;
    if (!a.length) return;
    let i;
    if (S.evIdx >= 0 && a[S.evIdx][0] === S.T) i = S.evIdx + dir;
    else i = dir > 0 ? lastAtOrBefore(a, S.T, (e) => e[0]) + 1 : lastAtOrBefore(a, S.T, (e) => e[0], true);
    i = Math.max(0, Math.min(a.length - 1, i));
    const e = a[i];
    S.evIdx = i; S.playing = false; S.follow = false;
    $("play").textContent = "Play";
    setT(e[0]);
    $("stepinfo").textContent = `event ${i + 1} of ${a.length}: t = ${(+e[0]).toFixed(6)} s ${e[1]} ${e[2]}` +
      `${e[3] ? " " + e[3] : ""}${e[10] != null ? ` #${e[10]} ${e[11] ?? ""} from ${e[9]}` : ""}`;
  }
  function ctlButtons() {                          // a message stays until the next one (never wiped by updates)
    const can = S.mode === "live" && !!S.doc.control;
    $("pause").disabled = !can; $("resume").disabled = !can;
    if (can === S.ctlCan) return;
    if (S.ctlCan !== undefined || !can) $("ctlmsg").textContent = S.mode !== "live" ? "" : can ? "control allowed" : "control not allowed";
    S.ctlCan = can;
  }

  // -- time ----------------------------------------------------------------------------------------
  function setT(T) {
    S.T = T;
    const sl = $("slider");
    if (document.activeElement !== sl || S.playing) sl.value = T;
  }
  function tick() {
    requestAnimationFrame(tick);                    // first: a frame that throws (bad data) never stops the page
    const now = performance.now() / 1000;
    const dt = S.lastWall == null ? 0 : now - S.lastWall;
    S.lastWall = now;
    if (S.ready) {
      const sl = $("slider");
      if (S.mode === "replay") {
        sl.min = S.doc.t0; sl.max = S.doc.t1;
        $("tmin").textContent = S.doc.t0.toFixed(1); $("tmax").textContent = S.doc.t1.toFixed(1);
        if (S.playing) {
          let T = S.T + dt * S.speed;
          if (T >= S.doc.t1) { T = S.doc.t1; S.playing = false; $("play").textContent = "Play"; }
          setT(T);
        }
      } else {
        const now_t = liveNow();
        sl.min = 0; sl.max = Math.max(now_t, 0.001);
        $("tmin").textContent = "0"; $("tmax").textContent = now_t.toFixed(1);
        if (S.follow) setT(now_t);
        $("follow").disabled = S.follow;
      }
      draw();
      panels(S.T);
    }
  }

  // -- wiring --------------------------------------------------------------------------------------
  $("slider").addEventListener("input", (e) => {
    S.T = parseFloat(e.target.value);
    if (S.mode === "live") S.follow = false;
  });
  $("play").addEventListener("click", () => {
    S.playing = !S.playing;
    if (S.playing && S.T >= S.doc.t1) S.T = S.doc.t0;
    $("play").textContent = S.playing ? "Stop" : "Play";
  });
  canvas.addEventListener("wheel", (e) => {
    e.preventDefault();
    const r = canvas.getBoundingClientRect();
    zoomAt(Math.exp(-e.deltaY * 0.0015), (e.clientX - r.left) * canvas.width / r.width, (e.clientY - r.top) * canvas.height / r.height);
  }, { passive: false });
  let drag = null, moved = 0;
  canvas.addEventListener("mousedown", (e) => { drag = [e.clientX, e.clientY]; moved = 0; });
  window.addEventListener("mouseup", (e) => {
    if (drag && moved < 4 && e.target === canvas) {   // a click, not a drag: the vehicle under it, if any
      const r = canvas.getBoundingClientRect();
      const x = (e.clientX - r.left) * canvas.width / r.width, y = (e.clientY - r.top) * canvas.height / r.height;
      let best = null, bd = DISC + 3;
      for (const v of Object.keys(S.doc.vehicles)) {
        const p = posAt(v, S.T);
        if (!p) continue;
        const q = toPx(p), dd = Math.hypot(q[0] - x, q[1] - y);
        if (dd <= bd) { best = v; bd = dd; }
      }
      if (best != null) select({ vehicle: best });
      else {                                         // else the link under it (the nearest within 5 px)
        let bl = null, bd2 = 5;
        for (const [tx, rx, a, b] of S.drawn || []) {
          const L2 = (b[0] - a[0]) ** 2 + (b[1] - a[1]) ** 2 || 1;
          const u = Math.max(0, Math.min(1, ((x - a[0]) * (b[0] - a[0]) + (y - a[1]) * (b[1] - a[1])) / L2));
          const dd = Math.hypot(a[0] + u * (b[0] - a[0]) - x, a[1] + u * (b[1] - a[1]) - y);
          if (dd <= bd2) { bl = [tx, rx]; bd2 = dd; }
        }
        if (bl) select({ link: bl });
      }
    }
    drag = null;
  });
  window.addEventListener("mousemove", (e) => {
    if (!drag) return;
    const r = canvas.getBoundingClientRect();
    moved += Math.abs(e.clientX - drag[0]) + Math.abs(e.clientY - drag[1]);
    V.dx += (e.clientX - drag[0]) * canvas.width / r.width; V.dy += (e.clientY - drag[1]) * canvas.height / r.height;
    drag = [e.clientX, e.clientY];
  });
  $("prev").addEventListener("click", () => step(-1));
  $("next").addEventListener("click", () => step(1));
  document.addEventListener("keydown", (e) => {      // , . and the arrows step by event (not while typing)
    if (e.target.closest && e.target.closest("input, select, textarea")) return;
    const dir = { ",": -1, ArrowLeft: -1, ".": 1, ArrowRight: 1 }[e.key];
    if (dir && !e.ctrlKey && !e.metaKey && !e.altKey) { e.preventDefault(); step(dir); }
  });
  $("linkby").addEventListener("change", (e) => { S.linkBy = e.target.value; linkMode(); });
  $("zoomin").addEventListener("click", () => zoomAt(1.5, canvas.width / 2, canvas.height / 2));
  $("zoomout").addEventListener("click", () => zoomAt(1 / 1.5, canvas.width / 2, canvas.height / 2));
  $("fit").addEventListener("click", () => { V.zoom = 1; V.dx = 0; V.dy = 0; });
  $("frames").addEventListener("click", (e) => {     // a frame's details, from the document (as text)
    const li = e.target.closest("li"), f = li && S.framesById.get(+li.dataset.id);
    if (!f) return;
    const outs = Object.entries(f.outcomes).map(([d, o]) => `  ${d}: ${o.outcome} at ${(+o.t).toFixed(6)} s`);
    S.sel = null;
    $("detail").textContent = [`frame ${f.dev} → ${f.dst} #${f.seq} ${f.kind} (try ${f.attempt}), channel ${f.ch}`,
      `sent at ${(+f.t).toFixed(6)} s`, "outcomes:", ...(outs.length ? outs : ["  none yet"])].join("\n");
  });
  $("speed").addEventListener("change", (e) => { S.speed = parseFloat(e.target.value); });
  $("follow").addEventListener("click", () => { S.follow = true; });
  for (const op of ["pause", "resume"]) {
    $(op).addEventListener("click", async () => {
      try {
        const r = await fetch(`api/control/${op}`, { method: "POST" });
        const j = await r.json();
        $("ctlmsg").textContent = j.ok ? `${op}d at t = ${(+j.t).toFixed(3)} s` : j.error;
      } catch (err) { $("ctlmsg").textContent = String(err); }
    });
  }

  function connect() {
    const ws = new WebSocket(location.href.replace(/^http/, "ws").replace(/[^/]*$/, "ws"));
    ws.binaryType = "arraybuffer";
    const dec = new TextDecoder();
    ws.onopen = () => { S.connected = true; $("conn").textContent = "connected"; };
    ws.onclose = () => { S.connected = false; $("conn").textContent = "disconnected"; setTimeout(connect, 1000); };
    ws.onmessage = (ev) => {
      const m = JSON.parse(typeof ev.data === "string" ? ev.data : dec.decode(ev.data));
      if (m.type === "snapshot") load(m.doc);
      else if (m.type === "updates") for (const u of m.updates) apply(u);
      ctlButtons();
    };
  }

  async function start() {
    const r = await fetch("api/doc", { cache: "no-store" });
    const doc = await r.json();
    if (doc.mode === "live") { load(doc); connect(); } else load(doc);
    requestAnimationFrame(tick);
  }

  // What tests (and curious users, from the console) can ask the page.
  window.uwsimnetView = {
    get ready() { return S.ready; },
    get T() { return S.T; },
    get mode() { return S.mode; },
    get updates() { return S.updates; },
    vehicles: () => Object.keys(S.doc.vehicles).length,
    modems: () => Object.keys(S.doc.devices).length,
    kinds: () => Object.fromEntries(Object.entries(S.doc.devices).map(([k, d]) => [k, d.kind])),
    position: (v) => posAt(v, S.T),
    pixel: (v) => toPx(posAt(v, S.T)),
    get zoom() { return V.zoom; },
    frame: (dev, seq, kind) => {
      for (let k = S.frames.length - 1; k >= 0; k--) {
        const f = S.frames[k];
        if (f.dev === dev && f.seq === seq && (kind == null || f.kind === kind)) return { ...frameStatus(f, S.T), t: f.t, id: f.id };
      }
      return null;
    },
    counters: (dev) => devState(dev, S.T),
    link: (tx, rx) => {                              // what the link tx -> rx is coloured by at the time shown
      const d = S.doc.devices[tx], p = devPos(tx, S.T), q = devPos(rx, S.T);
      const dist = p && q ? Math.hypot(p[0] - q[0], p[1] - q[1], p[2] - q[2]) : null;
      return { by: S.linkBy, value: d && dist != null ? linkLoss(tx, rx, d, dist, S.T) : null,
        measured: S.links.loss(tx, rx, S.T) };
    },
    setTime: (T) => { S.playing = false; S.follow = false; setT(T); },
    play: (speed) => { S.speed = speed || S.speed; S.playing = true; },
  };
  start();
})();
