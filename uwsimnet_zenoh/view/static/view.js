// uwsimnet view: one page for a replayed trace and a live world (docs/view.md).
// The document and updates are described in uwsimnet_zenoh/view/state.py.  No build step, no libraries.
"use strict";

(function () {
  const HOLD = 1.5;          // s of simulation time an outcome stays drawn at its receiver
  const TRAIL = 60;          // s of trail behind each vehicle
  const LIST = 40;           // frames in the list (the latest that pass the filters)
  const CAP = { frames: 4000, events: 5000, poses: 3000 };
  const COLORS = { rx: "#2ecc71", col: "#e74c3c", prop: "#b0b0b0", mult: "#ff8c1a", range: "#7f8c8d" };
  const $ = (id) => document.getElementById(id);

  const S = {
    doc: null, mode: "replay", T: 0, playing: false, speed: 1, follow: true, ready: false,
    framesById: new Map(), frames: [], evByDev: new Map(), maxDelay: 1, bounds: null, zr: [0, 1],
    circle: new Map(), lastWall: null, clockAt: 0, connected: false, updates: 0,
  };

  // -- helpers -----------------------------------------------------------------------------------
  function lastAtOrBefore(arr, T, key) {            // index of the last element with key(e) <= T, or -1
    let lo = 0, hi = arr.length - 1, ans = -1;
    while (lo <= hi) {
      const mid = (lo + hi) >> 1;
      if (key(arr[mid]) <= T) { ans = mid; lo = mid + 1; } else { hi = mid - 1; }
    }
    return ans;
  }
  function el(tag, cls, ...kids) {                  // an element whose data is text, never markup (#41)
    const e = document.createElement(tag);
    if (cls) e.className = cls;
    e.append(...kids.map((x) => (x instanceof Node ? x : String(x))));
    return e;
  }
  function perColor(p) {                             // 0 green, 0.5 yellow, 1 red
    p = Math.max(0, Math.min(1, p));
    const a = [46, 204, 113], b = [241, 196, 15], c = [231, 76, 60];
    const [u, v, f] = p < 0.5 ? [a, b, p * 2] : [b, c, (p - 0.5) * 2];
    return `rgb(${u.map((x, i) => Math.round(x + (v[i] - x) * f)).join(",")})`;
  }
  function depthColor(z) {
    const [lo, hi] = S.zr;
    const f = hi > lo ? (hi - z) / (hi - lo) : 0.5;  // z up: the highest (shallowest) light, the lowest dark
    const stops = [[246, 246, 122], [55, 200, 200], [42, 62, 168]];
    const g = Math.max(0, Math.min(1, f)) * 2, i = Math.min(1, Math.floor(g)), k = g - i;
    return `rgb(${stops[i].map((x, j) => Math.round(x + (stops[i + 1][j] - x) * k)).join(",")})`;
  }
  function perAt(dev, d) {                            // PER of dev's transmissions at distance d, or null
    const c = dev.per;
    if (!c || !c.length) return null;
    if (d <= c[0][0]) return c[0][1];
    for (let i = 1; i < c.length; i++) {
      if (d <= c[i][0]) {
        const [d0, p0] = c[i - 1], [d1, p1] = c[i];
        return p0 + (p1 - p0) * (d - d0) / (d1 - d0);
      }
    }
    return c[c.length - 1][1];
  }

  // -- the document --------------------------------------------------------------------------------
  function addFrame(f) {
    const old = S.framesById.get(f.id);
    if (old) { old.outcomes = f.outcomes; } else {
      S.framesById.set(f.id, f);
      S.frames.push(f);
      if (S.frames.length > CAP.frames && S.mode === "live") S.framesById.delete(S.frames.shift().id);
    }
    for (const o of Object.values(f.outcomes)) S.maxDelay = Math.max(S.maxDelay, o.t - f.t);
  }
  function addEvent(e) {
    let a = S.evByDev.get(e[1]);
    if (!a) { a = []; S.evByDev.set(e[1], a); }
    a.push(e);
    if (a.length > CAP.events && S.mode === "live") a.shift();
  }
  function load(doc) {
    S.doc = doc; S.mode = doc.mode;
    S.framesById = new Map(); S.frames = []; S.evByDev = new Map(); S.maxDelay = 1;
    for (const f of doc.frames) addFrame(f);
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
    else if (u.type === "devices") {
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
    for (const [id, d] of Object.entries(devs)) {
      const p = devPos(id, T);
      if (!p) continue;
      for (const [rid, r] of Object.entries(devs)) {
        if (rid === id || r.rx_channel !== d.tx_channel || r.vehicle === d.vehicle) continue;
        const q = devPos(rid, T);
        if (!q) continue;
        const dist = Math.hypot(p[0] - q[0], p[1] - q[1], p[2] - q[2]);
        if (dist < (d.min_distance || 0) || (d.max_distance != null && dist > d.max_distance)) continue;
        const per = S.doc.positions ? perAt(d, dist) : null;
        const a = toPx(p), b = toPx(q);
        const len = Math.hypot(b[0] - a[0], b[1] - a[1]) || 1, nx = -(b[1] - a[1]) / len * 2, ny = (b[0] - a[0]) / len * 2;
        ctx.strokeStyle = per == null ? "#5d6d7e" : perColor(per);
        ctx.globalAlpha = 0.75; ctx.lineWidth = 2; ctx.setLineDash(per == null ? [4, 4] : []);
        ctx.beginPath(); ctx.moveTo(a[0] + nx, a[1] + ny); ctx.lineTo(b[0] + nx, b[1] + ny); ctx.stroke();
        ctx.setLineDash([]); ctx.globalAlpha = 1;
      }
    }
  }
  function drawVehicles(T) {
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
      ctx.beginPath(); ctx.arc(x, y, 8, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
      ctx.fillStyle = "#dce6f0"; ctx.font = "12px sans-serif";
      ctx.fillText(S.doc.positions ? `${v} (z ${p[2].toFixed(1)})` : v, x + 11, y - 8);
    }
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
    const sig = items.map((li) => li.textContent + li.dataset.state).join("\n");
    if (sig !== S.listSig) { S.listSig = sig; $("frames").replaceChildren(...items); }   // unchanged: clickable
    $("clock").textContent = `t = ${T.toFixed(3)} s`;
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
    requestAnimationFrame(tick);
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
  let drag = null;
  canvas.addEventListener("mousedown", (e) => { drag = [e.clientX, e.clientY]; });
  window.addEventListener("mouseup", () => { drag = null; });
  window.addEventListener("mousemove", (e) => {
    if (!drag) return;
    const r = canvas.getBoundingClientRect();
    V.dx += (e.clientX - drag[0]) * canvas.width / r.width; V.dy += (e.clientY - drag[1]) * canvas.height / r.height;
    drag = [e.clientX, e.clientY];
  });
  $("zoomin").addEventListener("click", () => zoomAt(1.5, canvas.width / 2, canvas.height / 2));
  $("zoomout").addEventListener("click", () => zoomAt(1 / 1.5, canvas.width / 2, canvas.height / 2));
  $("fit").addEventListener("click", () => { V.zoom = 1; V.dx = 0; V.dy = 0; });
  $("frames").addEventListener("click", (e) => {     // a frame's details, from the document (as text)
    const li = e.target.closest("li"), f = li && S.framesById.get(+li.dataset.id);
    if (!f) return;
    const outs = Object.entries(f.outcomes).map(([d, o]) => `  ${d}: ${o.outcome} at ${(+o.t).toFixed(6)} s`);
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
    setTime: (T) => { S.playing = false; S.follow = false; setT(T); },
    play: (speed) => { S.speed = speed || S.speed; S.playing = true; },
  };
  start();
})();
