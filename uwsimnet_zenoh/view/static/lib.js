// uwsimnet view: the page's pure helpers (no page state): searches, text-only elements, colours, the curves
// and series of the modelled PER, and each link's outcomes for the measured loss (docs/view.md).
"use strict";

(function () {
  const LINK_WINDOW = 20;    // outcomes on a link the measured loss is taken over (the latest up to the time shown)
  const NOLINK = new Set(["range", "nopose"]);   // outcomes that say there was no link to measure

  function lastAtOrBefore(arr, T, key, strict) {    // index of the last element with key(e) <= T (< T), or -1
    let lo = 0, hi = arr.length - 1, ans = -1;
    while (lo <= hi) {
      const mid = (lo + hi) >> 1, k = key(arr[mid]);
      if (strict ? k < T : k <= T) { ans = mid; lo = mid + 1; } else { hi = mid - 1; }
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
  function perAt(dev, d) {                            // PER of dev's transmissions at distance d (its curve), or null
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
  function seriesAt(a, T, k = 1) {                   // column k of [[t, ...], ...] at T: linear in t, held outside
    const i = lastAtOrBefore(a, T, (e) => e[0]);
    if (i < 0) return a[0][k];
    if (i === a.length - 1 || a[i][k] == null || a[i + 1][k] == null) return a[i][k];
    const [t0, v0, t1, v1] = [a[i][0], a[i][k], a[i + 1][0], a[i + 1][k]];
    return v0 + (v1 - v0) * (T - t0) / (t1 - t0);
  }

  // Each link's receiver outcomes in time order, as [t, delivered so far, heard so far, delivered (0|1)]:
  // the measured loss over any window is two lookups.  `cap` bounds each link's list (live).
  class LinkStats {
    constructor(cap) { this.m = new Map(); this.cap = cap; }
    add(tx, rx, o) {
      if (NOLINK.has(o.outcome)) return;
      const k = tx + "\u0000" + rx, d = o.outcome === "rx" ? 1 : 0;
      let a = this.m.get(k);
      if (!a) { a = []; this.m.set(k, a); }
      const last = a[a.length - 1];
      if (last && o.t < last[0]) {                   // a live outcome that came late: keep the list in time order
        const obs = a.map((e) => [e[0], e[3]]).concat([[o.t, d]]).sort((x, y) => x[0] - y[0]);
        let r = a[0][1] - a[0][3], n = a[0][2] - 1;
        a.length = 0;
        for (const [t, dd] of obs) { r += dd; n++; a.push([t, r, n, dd]); }
      } else {
        a.push([o.t, (last ? last[1] : 0) + d, (last ? last[2] : 0) + 1, d]);
      }
      if (this.cap && a.length > this.cap) a.shift();
    }
    loss(tx, rx, T) {                                // {loss, got, n}: the last LINK_WINDOW outcomes up to T, or null
      const a = this.m.get(tx + "\u0000" + rx);
      const i = a ? lastAtOrBefore(a, T, (e) => e[0]) : -1;
      if (i < 0) return null;
      const s = Math.max(0, i - LINK_WINDOW + 1);
      const n = a[i][2] - (a[s][2] - 1), got = a[i][1] - (a[s][1] - a[s][3]);
      return { loss: 1 - got / n, got, n };
    }
  }

  window.uwsimnetLib = { LINK_WINDOW, lastAtOrBefore, el, perColor, perAt, seriesAt, LinkStats };
})();
