// uwsimnet view: where vehicle labels go (docs/view.md, "Labels").  A pure function, so the page and a
// test read the same boxes.  Greedy, as NetAnim-like viewers do: vehicles in a fixed order each take the
// first candidate box around their disc that overlaps no box already placed and no other disc; candidates
// go round the disc at growing distances, so a label far from its disc gets a leader line.
"use strict";

(function () {
  const DIRS = [[1, -1], [-1, -1], [1, 1], [-1, 1], [1, 0], [-1, 0], [0, -1], [0, 1]];
  const RINGS = [0, 14, 30, 50, 76, 110, 150];   // extra px between the disc and the box, ring by ring

  function overlaps(a, b) {                      // boxes [x, y, w, h]
    return a[0] < b[0] + b[2] && b[0] < a[0] + a[2] && a[1] < b[1] + b[3] && b[1] < a[1] + a[3];
  }
  function hitsDisc(b, d) {                      // box b against a disc [x, y, r]
    const cx = Math.max(b[0], Math.min(d[0], b[0] + b[2])), cy = Math.max(b[1], Math.min(d[1], b[1] + b[3]));
    return Math.hypot(cx - d[0], cy - d[1]) < d[2];
  }

  const CELL = 48;                               // px: a grid over the map so a box meets only its neighbours
  class Grid {
    constructor() { this.cells = new Map(); this.stamp = 0; }
    keys(b) {
      const out = [];
      for (let i = Math.floor(b[0] / CELL); i <= Math.floor((b[0] + b[2]) / CELL); i++) {
        for (let j = Math.floor(b[1] / CELL); j <= Math.floor((b[1] + b[3]) / CELL); j++) out.push(i * 65536 + j);
      }
      return out;
    }
    add(item, b) {
      for (const k of this.keys(b)) { let c = this.cells.get(k); if (!c) this.cells.set(k, c = []); c.push(item); }
    }
    near(b, fn) {                                // fn(item) once for every item in the cells b touches
      const s = ++this.stamp;
      for (const k of this.keys(b)) {
        for (const it of this.cells.get(k) || []) if (it.seen !== s) { it.seen = s; fn(it); }
      }
    }
  }

  // items: [{key, x, y, w, h}] (the disc centre in px, the label's size); r: the disc radius; W, H: the map.
  // Returns {key: {box: [x, y, w, h], leader: bool}}: boxes that do not intersect one another while the
  // candidates last (the least crowded candidate otherwise) and avoid every other disc.
  function place(items, r, W, H) {
    const order = [...items].sort((a, b) => a.y - b.y || a.x - b.x || (a.key < b.key ? -1 : 1));
    const grid = new Grid(), out = {};
    for (const it of order) grid.add({ disc: [it.x, it.y, r + 1] }, [it.x - r - 1, it.y - r - 1, 2 * r + 2, 2 * r + 2]);
    for (const it of order) {
      let best = null, bestCost = Infinity;
      for (let ring = 0; ring < RINGS.length && bestCost > 0; ring++) {
        for (const [ux, uy] of DIRS) {
          const g = r + 2 + RINGS[ring];
          const x = ux > 0 ? it.x + g : ux < 0 ? it.x - g - it.w : it.x - it.w / 2;
          const y = uy > 0 ? it.y + g : uy < 0 ? it.y - g - it.h : it.y - it.h / 2;
          const b = [x, y, it.w, it.h];
          let cost = x < 0 || y < 0 || x + it.w > W || y + it.h > H ? 0.5 : 0;   // off the map: only if nothing else
          grid.near(b, (o) => { cost += o.box ? (overlaps(b, o.box) ? 4 : 0) : (hitsDisc(b, o.disc) ? 1 : 0); });
          if (cost < bestCost) { best = b; bestCost = cost; }
          if (cost === 0) break;
        }
      }
      grid.add({ box: best }, best);
      const near = Math.hypot(Math.max(best[0] - it.x, 0, it.x - best[0] - best[2]),
        Math.max(best[1] - it.y, 0, it.y - best[1] - best[3]));
      out[it.key] = { box: best, leader: near > (r + 2) * 1.5 + 1 };
    }
    return out;
  }

  window.uwsimnetLabels = { place, overlaps };
})();
