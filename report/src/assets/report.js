/* gardefou report: draws the timelines of the maintenance report from the JSON
 * embedded in the page (#gardefou-data), and wires zoom, pan and the tooltip.
 *
 * The page is a single offline file: no modules, no libraries, no network.
 * Edges arrive delta-encoded; they are decoded once into Float64Arrays of absolute
 * ticks, and every redraw walks only the edges in view, one screen bin at a time,
 * so that a day-long log draws a few hundred shapes per band at any zoom.
 */
(function () {
  'use strict';

  const root = document.documentElement;

  // Geometry of a timeline, in CSS pixels.
  const LABEL_W = 128; // left gutter: signal and lane names
  const RIGHT_PAD = 16;
  const AXIS_H = 26;
  const BAND_H = 18;
  const BAND_GAP = 7;
  const DIAG_H = 26;
  const ROW_H = 20; // each row of the filter lane (trips, rewrites)
  const BOTTOM_PAD = 6;
  // Edges are merged per bin of this many pixels: a bin holding several edges is
  // drawn as one "busy" rect, which bounds the rects of a band by the plot width.
  const BIN_PX = 2;
  // Markers closer than this are summarised into one count.
  const CLUSTER_PX = 10;
  // Learned windows are shaded only when this few state entries are in view.
  const MAX_WINDOW_ENTRIES = 300;
  // Span of a zoom on an instant (data-zoom-t without data-zoom-span), in ns.
  const FOCUS_SPAN_NS = 20e9;

  const logs = new Map(); // String(log index) -> log model
  let timelineSerial = 0;
  let suppressClickUntil = 0;
  let drag = null;

  // ---------------------------------------------------------------- errors

  function fail(err) {
    const msg = (err && err.message) || String(err);
    if (!root.dataset.renderError) root.dataset.renderError = msg;
    console.error('gardefou report:', err);
    // Say so where the timelines should be, rather than leave blank space.
    try {
      for (const host of document.querySelectorAll('.timeline-host')) {
        if (host.childElementCount) continue;
        const p = document.createElement('p');
        p.className = 'timeline-missing';
        p.textContent = 'The timeline could not be drawn: ' + msg;
        host.appendChild(p);
      }
    } catch (e) {
      // the report itself is what failed: nothing more to show
    }
  }

  // Every entry point (init, event handlers, animation frames) goes through this,
  // so that a failure is reported once, visibly, instead of breaking silently.
  function guard(fn) {
    return function (...args) {
      try {
        return fn.apply(this, args);
      } catch (e) {
        fail(e);
        return undefined;
      }
    };
  }

  // ---------------------------------------------------------------- helpers

  /** Number of elements of the sorted array `a` that are <= x, within [lo, hi). */
  function upperBound(a, x, lo, hi) {
    lo = lo || 0;
    hi = hi === undefined ? a.length : hi;
    while (lo < hi) {
      const m = (lo + hi) >>> 1;
      if (a[m] <= x) lo = m + 1;
      else hi = m;
    }
    return lo;
  }

  /** First index in [lo, hi) of the sorted array `a` whose element is >= x. */
  function lowerBound(a, x, lo, hi) {
    lo = lo || 0;
    hi = hi === undefined ? a.length : hi;
    while (lo < hi) {
      const m = (lo + hi) >>> 1;
      if (a[m] < x) lo = m + 1;
      else hi = m;
    }
    return lo;
  }

  /** lowerBound starting from `from` by doubling steps: cheap when the answer is near. */
  function gallopLowerBound(a, x, from, hi) {
    let lo = from;
    let p = from;
    let step = 1;
    while (p < hi && a[p] < x) {
      lo = p + 1;
      p = from + step;
      step *= 2;
    }
    return lowerBound(a, x, lo, Math.min(p, hi));
  }

  function esc(s) {
    return String(s)
      .replace(/&/g, '&amp;')
      .replace(/</g, '&lt;')
      .replace(/>/g, '&gt;')
      .replace(/"/g, '&quot;');
  }

  function f1(x) {
    return (Math.round(x * 10) / 10).toString();
  }

  function clamp(x, lo, hi) {
    return x < lo ? lo : x > hi ? hi : x;
  }

  /** Verdict names mapped onto the three colours; unknown ones read as ambiguous. */
  function verdictClass(v) {
    return v === 'normal' || v === 'certain' ? v : 'ambiguous';
  }

  const SEVERITY = { normal: 0, ambiguous: 1, certain: 2 };

  /** Decodes delta-encoded tick times into absolute ticks. */
  function decodeEdges(deltas) {
    const n = Array.isArray(deltas) ? deltas.length : 0;
    const out = new Float64Array(n);
    let acc = 0;
    let sorted = true;
    for (let i = 0; i < n; i++) {
      const d = Number(deltas[i]) || 0;
      if (i > 0 && d < 0) sorted = false;
      acc += d;
      out[i] = acc;
    }
    // Binary searches need sorted times; a malformed stream is sorted rather than
    // drawn wrongly.
    if (!sorted) out.sort();
    return out;
  }

  function estimateTextWidth(s, px) {
    return String(s).length * (px || 11) * 0.6;
  }

  function hatName(sensors) {
    // "C4" -> "Ĉ4": the estimate of a sensor, as written in the docs.
    return String(sensors)
      .split(/\s+/)
      .filter(Boolean)
      .map((s) => s[0] + '\u0302' + s.slice(1))
      .join(', ');
  }

  // ---------------------------------------------------------------- time labels

  function ticksToMs(log, ticks) {
    return (ticks * log.tickNs) / 1e6;
  }

  /** Offset from the log's start, "+H:MM:SS" with `dec` decimals of seconds. */
  function fmtOffset(log, ticks, dec) {
    const scale = Math.pow(10, dec);
    const total = Math.round((ticksToMs(log, Math.max(0, ticks)) / 1000) * scale);
    const secs = Math.floor(total / scale);
    const frac = total - secs * scale;
    const h = Math.floor(secs / 3600);
    const m = Math.floor((secs % 3600) / 60);
    const s = secs % 60;
    // Hours are written when the log lasts an hour or more, so that all labels of
    // one log read alike; shorter logs read "+M:SS.mmm" as the page's tables do.
    const withHours = h > 0 || log.hourly;
    let out = '+' + (withHours ? h + ':' + String(m).padStart(2, '0') : String(m)) + ':' + String(s).padStart(2, '0');
    if (dec > 0) out += '.' + String(frac).padStart(dec, '0');
    return out;
  }

  /** Decimals of seconds worth showing for a given resolution in ms. */
  function decimalsFor(resolutionMs) {
    if (resolutionMs >= 1000) return 0;
    if (resolutionMs >= 1) return 3;
    return 6;
  }

  function fmtNumber(v) {
    if (!isFinite(v)) return String(v);
    return String(parseFloat(v.toFixed(6)));
  }

  /** Absolute time of an instant, from the log's `time` description. */
  function fmtAbsolute(log, ticks) {
    const tm = log.time || {};
    if (tm.kind === 'rfc3339' && isFinite(Number(tm.start_epoch_ms))) {
      const d = new Date(Number(tm.start_epoch_ms) + ticksToMs(log, ticks));
      return isNaN(d.getTime()) ? '' : d.toISOString();
    }
    if (tm.kind === 'numeric') {
      const unitNs = Number(tm.unit_ns) > 0 ? Number(tm.unit_ns) : log.tickNs;
      const v = (Number(tm.start) || 0) + (ticks * log.tickNs) / unitNs;
      return (fmtNumber(v) + ' ' + (tm.unit || '')).trim();
    }
    return '';
  }

  function fmtSpan(log, ticks) {
    const ms = ticksToMs(log, ticks);
    if (ms < 1) return fmtNumber(Number(ms.toPrecision(3))) + ' ms';
    if (ms < 1000) return fmtNumber(Math.round(ms * 10) / 10) + ' ms';
    if (ms < 60e3) return fmtNumber(Math.round(ms / 10) / 100) + ' s';
    if (ms < 3600e3) return fmtNumber(Math.round(ms / 600) / 100) + ' min';
    return fmtNumber(Math.round(ms / 36e3) / 100) + ' h';
  }

  // Axis steps, in ms: 1-2-5 below a second, then clock-friendly steps.
  const NICE_MS = [
    0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5,
    1, 2, 5, 10, 20, 50, 100, 200, 500,
    1e3, 2e3, 5e3, 10e3, 15e3, 30e3,
    60e3, 120e3, 300e3, 600e3, 900e3, 1800e3,
    3600e3, 7200e3, 10800e3, 21600e3, 43200e3, 86400e3,
  ];

  function niceStepMs(targetMs) {
    for (const s of NICE_MS) if (s >= targetMs) return s;
    const day = 86400e3;
    return Math.ceil(targetMs / day) * day;
  }

  // ---------------------------------------------------------------- model

  function buildEvents(list, partName) {
    const evs = (Array.isArray(list) ? list : [])
      .filter((e) => e && isFinite(Number(e.t)))
      .filter((e) => !Array.isArray(e.parts) || e.parts.length === 0 || e.parts.indexOf(partName) >= 0)
      .slice()
      .sort((a, b) => a.t - b.t);
    const times = new Float64Array(evs.length);
    for (let i = 0; i < evs.length; i++) times[i] = Number(evs[i].t);
    return { list: evs, times };
  }

  function buildPart(p, log) {
    const signals = (p.signals || []).map((s, i) => {
      const edges = decodeEdges(s.edges);
      if (edges.length) log.extent = Math.max(log.extent, edges[edges.length - 1]);
      return {
        index: i,
        name: String(s.name),
        kind: s.kind === 'actuator' ? 'actuator' : 'sensor',
        description: s.description || '',
        init: Number(s.init) ? 1 : 0,
        edges,
      };
    });
    const verdicts = (Array.isArray(p.verdicts) ? p.verdicts : [])
      .filter((v) => v && isFinite(Number(v.t)))
      .slice()
      .sort((a, b) => a.t - b.t);
    const vTimes = new Float64Array(verdicts.length);
    // Flags newly raised by each verdict change (absent from the previous one).
    let prevFlags = [];
    const raised = verdicts.map((v, i) => {
      vTimes[i] = Number(v.t);
      const flags = Array.isArray(v.flags) ? v.flags : [];
      const fresh = flags.filter((f) => prevFlags.indexOf(f) < 0);
      prevFlags = flags;
      return fresh;
    });
    if (verdicts.length) log.extent = Math.max(log.extent, vTimes[vTimes.length - 1]);

    const windows = p.windows && typeof p.windows === 'object' ? p.windows : {};
    let maxHi = 0;
    let hasWindows = false;
    for (const key of Object.keys(windows)) {
      for (const w of windows[key] || []) {
        hasWindows = true;
        maxHi = Math.max(maxHi, Number(w.hi) || 0);
      }
    }
    const filter = log.raw.filter || {};
    const trips = buildEvents(filter.trips, p.name);
    const rewrites = buildEvents(filter.rewrites, p.name);
    for (const ev of [trips, rewrites]) {
      if (ev.times.length) log.extent = Math.max(log.extent, ev.times[ev.times.length - 1]);
    }
    return {
      name: String(p.name),
      verdict: p.verdict,
      signals,
      actuators: signals.filter((s) => s.kind === 'actuator'),
      verdicts: { list: verdicts, times: vTimes, raised },
      windows,
      hasWindows,
      maxHi,
      trips,
      rewrites,
    };
  }

  function buildLog(raw, pos) {
    const tickNs = Number(raw.tick_ns) > 0 ? Number(raw.tick_ns) : 1e6;
    const log = {
      raw,
      key: String(raw.index !== undefined && raw.index !== null ? raw.index : pos),
      name: raw.name || '',
      tickNs,
      time: raw.time || null,
      extent: Math.max(0, Number(raw.duration) || 0),
      parts: new Map(),
      timelines: [],
      toolbars: [],
      view: null,
      hoverT: null,
      frame: 0,
    };
    for (const p of raw.parts || []) log.parts.set(String(p.name), buildPart(p, log));
    // Which part's timeline an explanation belongs to, for clicks from outside the
    // part's section (the filter's trip explanations).
    log.explanationPart = new Map();
    for (const part of log.parts.values()) {
      for (const v of part.verdicts.list) if (v.explanation) log.explanationPart.set(String(v.explanation), part.name);
    }
    const trips = (raw.filter && raw.filter.trips) || [];
    for (const t of trips) {
      if (t && t.explanation && Array.isArray(t.parts) && t.parts.length && !log.explanationPart.has(t.explanation)) {
        log.explanationPart.set(String(t.explanation), String(t.parts[0]));
      }
    }
    if (!(log.extent > 0)) log.extent = 1;
    // Never zoom below 10 ms (or 8 ticks): finer than any scan period of interest.
    log.minSpan = Math.min(log.extent, Math.max(8, 1e7 / tickNs));
    log.view = { t0: 0, t1: log.extent };
    log.hourly = ticksToMs(log, log.extent) >= 3600e3;
    return log;
  }

  // ---------------------------------------------------------------- view

  function setView(log, t0, span) {
    span = clamp(span, log.minSpan, log.extent);
    t0 = clamp(t0, 0, log.extent - span);
    log.view = { t0, t1: t0 + span };
    updateRangeText(log);
  }

  function zoomAround(log, t, factor) {
    const { t0, t1 } = log.view;
    const span = t1 - t0;
    const next = clamp(span * factor, log.minSpan, log.extent);
    setView(log, t - ((t - t0) * next) / span, next);
  }

  function centreOn(log, t, span) {
    span = clamp(span, log.minSpan, log.extent);
    setView(log, t - span / 2, span);
  }

  function fit(log) {
    setView(log, 0, log.extent);
  }

  function updateRangeText(log) {
    const { t0, t1 } = log.view;
    const dec = ticksToMs(log, t1 - t0) >= 600e3 ? 0 : 3;
    const text =
      fmtOffset(log, t0, dec) + ' \u2013 ' + fmtOffset(log, t1, dec) + '  (' + fmtSpan(log, t1 - t0) + ')';
    const a0 = fmtAbsolute(log, t0);
    const a1 = fmtAbsolute(log, t1);
    for (const tb of log.toolbars) {
      const span = tb.querySelector('span.range');
      if (!span) continue;
      span.textContent = text;
      if (a0) span.title = a0 + ' \u2013 ' + a1;
    }
  }

  /**
   * Draws timelines at their known widths. Widths are read once at start, then
   * kept up to date by resize notifications: reading a width right after changing
   * the page forces a layout, which would cost more than the drawing itself.
   */
  function renderAll(tls) {
    for (const tl of tls) renderTimeline(tl);
  }

  function measureWidth(tl) {
    return Math.max(360, Math.floor(tl.host.clientWidth || 960));
  }

  function renderLog(log) {
    if (log.frame) {
      cancelAnimationFrame(log.frame);
      log.frame = 0;
    }
    renderAll(log.timelines);
  }

  /**
   * Continuous gestures (wheel, drag) redraw at most once per frame, and only the
   * timelines on screen; the others catch up once the gesture pauses, or when
   * they scroll into view.
   */
  function scheduleRender(log) {
    if (log.frame) return;
    log.frame = requestAnimationFrame(
      guard(() => {
        log.frame = 0;
        for (const tl of log.timelines) {
          if (tl.onScreen) renderTimeline(tl);
          else tl.stale = true;
        }
        clearTimeout(log.catchUp);
        log.catchUp = setTimeout(
          guard(() => {
            for (const tl of log.timelines) if (tl.stale) renderTimeline(tl);
          }),
          60
        );
      })
    );
  }

  // ---------------------------------------------------------------- drawing

  function geometry(tl) {
    const width = tl.width;
    const plotW = Math.max(40, width - LABEL_W - RIGHT_PAD);
    const { t0, t1 } = tl.log.view;
    const tpp = (t1 - t0) / plotW; // ticks per pixel
    return { width, plotW, t0, t1, tpp, x: (t) => LABEL_W + (t - t0) / tpp };
  }

  function layout(part) {
    const bandTop = AXIS_H;
    const diagTop = bandTop + part.signals.length * (BAND_H + BAND_GAP) + 4;
    const filterTop = diagTop + DIAG_H + 6;
    const height = filterTop + 2 * ROW_H + BOTTOM_PAD;
    return { bandTop, diagTop, filterTop, height };
  }

  function drawAxis(log, g, height) {
    const targetMs = ticksToMs(log, g.tpp * 110);
    const stepMs = niceStepMs(targetMs);
    const stepT = (stepMs * 1e6) / log.tickNs;
    const dec = decimalsFor(stepMs);
    let s = '<g class="axis">';
    s += `<line class="axis-line" x1="${LABEL_W}" x2="${f1(LABEL_W + g.plotW)}" y1="${AXIS_H - 4.5}" y2="${AXIS_H - 4.5}"/>`;
    const first = Math.ceil(g.t0 / stepT);
    const last = Math.floor(g.t1 / stepT);
    for (let k = first; k <= last && k - first < 200; k++) {
      const t = k * stepT;
      const x = f1(g.x(t));
      s += `<line class="grid" x1="${x}" x2="${x}" y1="${AXIS_H - 8}" y2="${height - BOTTOM_PAD}"/>`;
      const label = fmtOffset(log, t, dec);
      // A label at the right end is anchored inward so that it is not cut.
      const half = estimateTextWidth(label, 10) / 2;
      const anchor = g.x(t) + half > g.width - 2 ? ' text-anchor="end"' : '';
      s += `<text class="tick" x="${x}" y="${AXIS_H - 11}"${anchor}>${label}</text>`;
    }
    s += '</g>';
    return s;
  }

  /** Time at 1 of a signal from tick 0 up to each of its edges (for duty cycles). */
  function onTimePrefix(sig) {
    const E = sig.edges;
    const n = E.length;
    const cum = new Float64Array(n);
    if (n === 0) return cum;
    cum[0] = sig.init ? E[0] : 0;
    for (let k = 1; k < n; k++) cum[k] = cum[k - 1] + ((sig.init ^ (k & 1)) ? E[k] - E[k - 1] : 0);
    return cum;
  }

  /**
   * Shapes of one band: value-1 stretches as rects; bins of BIN_PX pixels that
   * hold several edges as grey "busy" rects (merged along runs), with one path
   * over them whose height is the share of each bin spent at 1. Bins are aligned
   * on absolute time so that the picture does not flicker while panning.
   */
  function drawBandShapes(sig, g, y) {
    const E = sig.edges;
    const binT = BIN_PX * g.tpp;
    const plotEnd = g.plotW;
    const onY = y + 3;
    const onH = BAND_H - 3;
    const base = y + BAND_H;
    const busyY = y + 1;
    const busyH = BAND_H - 1;
    let s = '';
    let duty = '';
    let dutyY = NaN;
    let onStart = -1;
    let onEnd = -1;
    let busyStart = -1;
    let busyEnd = -1;
    let count = 0;
    let cum = null;

    // Time at 1 in [0, t], given k, the number of edges before t.
    function onUntil(t, k) {
      if (k === 0) return sig.init ? t : 0;
      return cum[k - 1] + ((sig.init ^ (k & 1)) ? t - E[k - 1] : 0);
    }
    function flushOn() {
      if (onStart < 0) return;
      const w = Math.max(1, onEnd - onStart);
      s += `<rect class="on" x="${f1(LABEL_W + onStart)}" y="${onY}" width="${f1(w)}" height="${onH}"/>`;
      count++;
      onStart = -1;
    }
    function addOn(a, b) {
      if (b <= a) return; // nothing between two busy bins
      if (onStart >= 0 && a - onEnd < 0.5) {
        onEnd = Math.max(onEnd, b);
        return;
      }
      flushOn();
      onStart = a;
      onEnd = b;
    }
    function flushBusy() {
      if (busyStart < 0) return;
      s += `<rect class="busy" x="${f1(LABEL_W + busyStart)}" y="${busyY}" width="${f1(busyEnd - busyStart)}" height="${busyH}"/>`;
      duty += `H${f1(LABEL_W + busyEnd)}V${base}Z`;
      count++;
      busyStart = -1;
    }
    function addBusy(a, b, d) {
      if (!(busyStart >= 0 && a - busyEnd < 0.01)) {
        flushBusy();
        busyStart = a;
        duty += `M${f1(LABEL_W + a)},${base}`;
        dutyY = NaN;
      }
      busyEnd = b;
      const top = f1(base - clamp(d, 0, 1) * onH);
      if (top !== dutyY) {
        duty += `H${f1(LABEL_W + a)}V${top}`;
        dutyY = top;
      }
    }

    // Value at the left edge: the initial value toggled by every edge <= t0.
    let i = upperBound(E, g.t0);
    let v = sig.init ^ (i & 1);
    const end = upperBound(E, g.t1, i);
    let pos = 0;
    while (i < end) {
      const b = Math.floor(E[i] / binT);
      const binEnd = (b + 1) * binT;
      const j = Math.min(end, Math.max(i + 1, gallopLowerBound(E, binEnd, i, end)));
      const k = j - i;
      if (k === 1) {
        const x = Math.min(plotEnd, (E[i] - g.t0) / g.tpp);
        if (v) addOn(pos, x);
        v ^= 1;
        pos = x;
      } else {
        if (!cum) cum = sig.cum || (sig.cum = onTimePrefix(sig));
        const tb0 = Math.max(0, b * binT);
        const d = (onUntil(binEnd, j) - onUntil(tb0, i)) / (binEnd - tb0);
        const bx0 = Math.max(pos, (b * binT - g.t0) / g.tpp);
        const bx1 = Math.min(plotEnd, (binEnd - g.t0) / g.tpp);
        if (v) addOn(pos, bx0);
        flushOn();
        addBusy(bx0, bx1, d);
        v ^= k & 1;
        pos = bx1;
      }
      i = j;
    }
    if (v) addOn(pos, plotEnd);
    flushOn();
    flushBusy();
    if (duty) s += `<path class="duty" d="${duty}"/>`;
    return { svg: s, count };
  }

  /** Value of a signal at tick t: its initial value toggled by every edge <= t. */
  function valueAt(sig, t) {
    return sig.init ^ (upperBound(sig.edges, t) & 1);
  }

  /**
   * Learned windows in view: for each state entry (an instant where some signal of
   * the part changes) whose state vector has windows, [cmd + lo, cmd + hi] where
   * cmd is the part's last actuator edge at or before the entry.
   * Returns null when too many entries are in view to stay light.
   */
  function windowsInView(part, g) {
    if (!part.hasWindows || part.actuators.length === 0) return [];
    const from = g.t0 - part.maxHi; // earlier entries have windows ending before t0
    let total = 0;
    const ranges = part.signals.map((sig) => {
      const a = upperBound(sig.edges, from - 1);
      const b = upperBound(sig.edges, g.t1);
      total += b - a;
      return [a, b];
    });
    if (total > MAX_WINDOW_ENTRIES) return null;
    const entries = [];
    part.signals.forEach((sig, k) => {
      for (let i = ranges[k][0]; i < ranges[k][1]; i++) entries.push(sig.edges[i]);
    });
    entries.sort((a, b) => a - b);
    const out = [];
    const seen = new Set();
    let prev = NaN;
    for (const te of entries) {
      if (te === prev) continue; // simultaneous edges enter one state
      prev = te;
      let key = '';
      for (const sig of part.signals) key += valueAt(sig, te);
      const ws = part.windows[key];
      if (!ws || !ws.length) continue;
      let cmd = -Infinity;
      for (const act of part.actuators) {
        const c = upperBound(act.edges, te);
        if (c > 0) cmd = Math.max(cmd, act.edges[c - 1]);
      }
      if (cmd === -Infinity) continue;
      for (const w of ws) {
        const a = cmd + (Number(w.lo) || 0);
        const b = cmd + (Number(w.hi) || 0);
        if (b < g.t0 || a > g.t1) continue;
        const id = w.signal + '|' + a + '|' + b;
        if (seen.has(id)) continue;
        seen.add(id);
        out.push({ signal: String(w.signal), event: w.event || '', lo: w.lo, hi: w.hi, a, b, state: key });
      }
    }
    return out;
  }

  /** Text of a count pill, and the pill's width in pixels. */
  function countLabel(n) {
    return n > 999 ? Math.round(n / 100) / 10 + 'k' : String(n);
  }

  function pillWidth(n) {
    return Math.max(14, 8 + countLabel(n).length * 6.5);
  }

  /**
   * Greedy clustering of the events in view: the events within CLUSTER_PX of the
   * first of a group join it, and a group of several widens to fit its count, so
   * that summaries never overlap. Bounded by the plot width whatever the density.
   */
  function clusters(times, g) {
    const i0 = lowerBound(times, g.t0);
    const i1 = upperBound(times, g.t1);
    const out = [];
    let i = i0;
    while (i < i1) {
      const x = g.x(times[i]);
      let ext = CLUSTER_PX;
      let j = Math.min(i1, Math.max(i + 1, lowerBound(times, times[i] + ext * g.tpp, i, i1)));
      for (let round = 0; round < 4 && j - i > 1; round++) {
        const need = pillWidth(j - i) + 2;
        if (need <= ext) break;
        ext = need;
        j = lowerBound(times, times[i] + ext * g.tpp, j, i1);
      }
      out.push({ from: i, to: j, x, x1: j - i > 1 ? x + ext - 2 : x, plotW: g.plotW });
      i = j;
    }
    return out;
  }

  function roomAfter(list, k, g) {
    const next = k + 1 < list.length ? list[k + 1].x : LABEL_W + g.plotW + RIGHT_PAD;
    return next - list[k].x;
  }

  function clusterShape(c, cls, y, h, title, rangeFrom, rangeTo) {
    const n = c.to - c.from;
    const label = countLabel(n);
    // The pill covers the stretch it summarises, from its first event on, and
    // stays inside the plot at the right edge.
    const w = Math.max(pillWidth(n), c.x1 - c.x);
    const x = Math.max(LABEL_W, Math.min(c.x, LABEL_W + c.plotW - w));
    const cx = x + w / 2;
    return (
      `<g class="cluster ${cls}" data-range="${rangeFrom} ${rangeTo}" data-count="${n}">` +
      `<title>${esc(title)}</title>` +
      `<rect x="${f1(x)}" y="${y}" width="${f1(w)}" height="${h}" rx="3"/>` +
      `<text x="${f1(cx)}" y="${y + h / 2}">${label}</text></g>`
    );
  }

  function countSummary(items, keyOf) {
    const counts = new Map();
    for (const it of items) {
      const k = keyOf(it);
      counts.set(k, (counts.get(k) || 0) + 1);
    }
    return Array.from(counts.entries())
      .sort((a, b) => b[1] - a[1])
      .slice(0, 4)
      .map(([k, n]) => k + ' \u00d7' + n)
      .join(', ');
  }

  function drawDiagnosisLane(tl, g, top, clip) {
    const { log, part } = tl;
    const V = part.verdicts;
    let s = `<g class="lane" data-lane="diagnosis">`;
    s += `<text class="lane-label" x="${LABEL_W - 8}" y="${top + DIAG_H / 2}">diagnosis</text>`;
    s += `<g clip-path="url(#${clip})">`;

    // Verdict in force, as a strip along the bottom of the lane (normal before the
    // first change); changes within one pixel keep the latest colour.
    const barY = top + DIAG_H - 5;
    const i0 = upperBound(V.times, g.t0);
    let cur = i0 > 0 ? verdictClass(V.list[i0 - 1].verdict) : 'normal';
    let segX = LABEL_W;
    const i1 = upperBound(V.times, g.t1);
    const segs = [];
    const push = (a, b, c) => {
      const last = segs[segs.length - 1];
      if (last && last[2] === c) last[1] = b;
      else segs.push([a, b, c]);
    };
    for (let i = i0; i < i1; i++) {
      const x = g.x(V.times[i]);
      if (x - segX >= 1) {
        push(segX, x, cur);
        segX = x;
      }
      cur = verdictClass(V.list[i].verdict);
    }
    push(segX, LABEL_W + g.plotW, cur);
    for (const seg of segs) {
      s += `<rect class="verdict-bar v-${seg[2]}" x="${f1(seg[0])}" y="${barY}" width="${f1(Math.max(1, seg[1] - seg[0]))}" height="4"/>`;
    }

    const cs = clusters(V.times, g);
    cs.forEach((c, k) => {
      if (c.to - c.from === 1) {
        const i = c.from;
        const v = V.list[i];
        const cls = verdictClass(v.verdict);
        const labels = Array.isArray(v.labels) ? v.labels : [];
        const fresh = V.raised[i];
        const text = labels.length ? labels.join(' ') : String(v.verdict || '');
        const x = c.x;
        let title = `${v.verdict} ${labels.join(', ')} at ${fmtOffset(log, v.t, 3)}`;
        if (fresh.length) title += `\nraises ${fresh.join(', ')}`;
        if (v.reason) title += `\n${v.reason}`;
        if (v.explanation) title += '\n(click: explanation)';
        const goto = v.explanation ? ` data-goto="${esc(v.explanation)}"` : '';
        s += `<g class="verdict v-${cls}" data-t="${v.t}" data-verdict="${esc(v.verdict)}"${goto}>`;
        s += `<title>${esc(title)}</title>`;
        s += `<line x1="${f1(x)}" x2="${f1(x)}" y1="${top + 2}" y2="${barY}"/>`;
        s += `<path class="marker" d="M${f1(x - 5)},${top + 1}h10l-5,8z"/>`;
        const room = roomAfter(cs, k, g) - 10;
        let tx = x + 7;
        const tw = estimateTextWidth(text, 11);
        if (tw < room) {
          s += `<text class="verdict-label" x="${f1(tx)}" y="${top + 9}">${esc(text)}</text>`;
          tx += tw + 6;
        }
        if (fresh.length) {
          const ftxt = fresh.join(' ');
          const fw = estimateTextWidth(ftxt, 10);
          if (tx - x + 10 < room) {
            s += `<path class="flag" d="M${f1(tx)},${top + 16}v-13h8l-2.5,3.5l2.5,3.5h-8"/>`;
            if (tx - x + 12 + fw < room) {
              s += `<text class="flag-label" x="${f1(tx + 11)}" y="${top + 9}">${esc(ftxt)}</text>`;
            }
          }
        }
        s += '</g>';
      } else {
        const items = V.list.slice(c.from, c.to);
        let worst = 'normal';
        for (const it of items) {
          const vc = verdictClass(it.verdict);
          if (SEVERITY[vc] > SEVERITY[worst]) worst = vc;
        }
        const title =
          `${items.length} verdict changes, ${fmtOffset(log, items[0].t, 3)} \u2013 ` +
          `${fmtOffset(log, items[items.length - 1].t, 3)}: ` +
          countSummary(items, (it) => it.verdict) +
          '\n(click: zoom in)';
        s += clusterShape(c, 'v-' + worst, top + 1, 14, title, V.times[c.from], V.times[c.to - 1]);
      }
    });
    s += '</g></g>';
    return s;
  }

  function drawFilterLane(tl, g, top, clip) {
    const { log, part } = tl;
    let s = `<g class="lane" data-lane="filter">`;
    const rows = [
      { name: 'trips', ev: part.trips, y: top },
      { name: 'rewrites', ev: part.rewrites, y: top + ROW_H },
    ];
    for (const row of rows) {
      const y = row.y;
      const mid = y + ROW_H / 2;
      s += `<text class="lane-label" x="${LABEL_W - 8}" y="${mid}">${row.name}</text>`;
      s += `<line class="lane-rule" x1="${LABEL_W}" x2="${f1(LABEL_W + g.plotW)}" y1="${mid}" y2="${mid}"/>`;
      s += `<g clip-path="url(#${clip})">`;
      const cs = clusters(row.ev.times, g);
      cs.forEach((c, k) => {
        if (c.to - c.from === 1) {
          const ev = row.ev.list[c.from];
          const x = c.x;
          const room = roomAfter(cs, k, g) - 10;
          let text;
          let title;
          let shape;
          let cls;
          if (row.name === 'trips') {
            cls = 'trip';
            const lits = Array.isArray(ev.literals) ? ev.literals.join(' \u2227 ') : '';
            text = String(ev.constraint || 'trip');
            title = `${text}` + (lits ? `: ${lits}` : '') + `\nstarts to hold at ${fmtOffset(log, ev.t, 3)}`;
            shape = `<path class="marker" d="M${f1(x)},${y + 3}l5,7l-5,7l-5,-7z"/>`;
          } else {
            cls = 'rewrite';
            const cons = Array.isArray(ev.constraints) ? ev.constraints.join(', ') : '';
            text = String(ev.flag || 'rewrite');
            title =
              `${text}: ` +
              (cons ? `${cons} read ${hatName(ev.sensor || '')}` : 'no constraint rewritten') +
              `\nraised at ${fmtOffset(log, ev.t, 3)}`;
            shape = `<rect class="marker" x="${f1(x - 4)}" y="${y + 5}" width="8" height="10" rx="1"/>`;
          }
          if (ev.explanation) title += '\n(click: explanation)';
          const goto = ev.explanation ? ` data-goto="${esc(ev.explanation)}"` : '';
          s += `<g class="${cls}" data-t="${ev.t}"${goto}><title>${esc(title)}</title>${shape}`;
          if (estimateTextWidth(text, 10) < room) {
            s += `<text x="${f1(x + 7)}" y="${mid}">${esc(text)}</text>`;
          }
          s += '</g>';
        } else {
          const items = row.ev.list.slice(c.from, c.to);
          const keyOf = row.name === 'trips' ? (it) => it.constraint : (it) => it.flag;
          const title =
            `${items.length} ${row.name}, ${fmtOffset(log, items[0].t, 3)} \u2013 ` +
            `${fmtOffset(log, items[items.length - 1].t, 3)}: ${countSummary(items, keyOf)}\n(click: zoom in)`;
          const cls = row.name === 'trips' ? 'trip' : 'rewrite';
          s += clusterShape(c, cls, y + 3, ROW_H - 6, title, row.ev.times[c.from], row.ev.times[c.to - 1]);
        }
      });
      s += '</g>';
    }
    s += '</g>';
    return s;
  }

  function renderTimeline(tl) {
    const { log, part } = tl;
    const width = tl.width;
    const g = geometry(tl);
    const lay = layout(part);
    const clipId = 'gf-clip-' + tl.serial;

    let s = `<defs><clipPath id="${clipId}"><rect x="${LABEL_W}" y="0" width="${f1(g.plotW)}" height="${lay.height}"/></clipPath></defs>`;
    s += drawAxis(log, g, lay.height);

    const wins = windowsInView(part, g);
    const winsBySignal = new Map();
    if (wins) {
      for (const w of wins) {
        if (!winsBySignal.has(w.signal)) winsBySignal.set(w.signal, []);
        winsBySignal.get(w.signal).push(w);
      }
    }

    part.signals.forEach((sig, k) => {
      const y = lay.bandTop + k * (BAND_H + BAND_GAP);
      const shortName = sig.name.length > 18 ? sig.name.slice(0, 17) + '\u2026' : sig.name;
      const desc = sig.name + ' (' + sig.kind + ')' + (sig.description ? ': ' + sig.description : '');
      s += `<g class="band ${sig.kind}" data-signal="${esc(sig.name)}">`;
      s += `<g class="label"><title>${esc(desc)}</title><text x="${LABEL_W - 8}" y="${y + BAND_H / 2 + 1}">${esc(shortName)}</text></g>`;
      s += `<line class="zero" x1="${LABEL_W}" x2="${f1(LABEL_W + g.plotW)}" y1="${y + BAND_H - 0.5}" y2="${y + BAND_H - 0.5}"/>`;
      s += `<g clip-path="url(#${clipId})">`;
      for (const w of winsBySignal.get(sig.name) || []) {
        const xa = Math.max(LABEL_W - 1, g.x(w.a));
        const xb = Math.min(LABEL_W + g.plotW + 1, g.x(w.b));
        s +=
          `<rect class="window" x="${f1(xa)}" y="${y - 2}" width="${f1(Math.max(1, xb - xa))}" height="${BAND_H + 3}">` +
          `<title>${esc(
            `${w.event || w.signal} expected ${fmtSpan(log, Number(w.lo) || 0)} to ${fmtSpan(log, Number(w.hi) || 0)} ` +
              `after the last command (state ${w.state})`
          )}</title></rect>`;
      }
      s += drawBandShapes(sig, g, y).svg;
      s += '</g></g>';
    });

    s += drawDiagnosisLane(tl, g, lay.diagTop, clipId);
    s += drawFilterLane(tl, g, lay.filterTop, clipId);
    s += `<line class="cursor" x1="0" x2="0" y1="${AXIS_H - 6}" y2="${lay.height - BOTTOM_PAD}" visibility="hidden"/>`;

    tl.stale = false;
    const svg = tl.svg;
    svg.setAttribute('width', String(width));
    svg.setAttribute('height', String(lay.height));
    svg.setAttribute('viewBox', `0 0 ${width} ${lay.height}`);
    svg.innerHTML = s;
    tl.cursor = svg.lastElementChild;
    svg.dataset.windows = wins ? 'shown' : 'too-many';
    showCursor(tl, log.hoverT);
  }

  // ---------------------------------------------------------------- hover

  function showCursor(tl, t) {
    if (!tl.cursor) return;
    if (t === null || t < tl.log.view.t0 || t > tl.log.view.t1) {
      tl.cursor.setAttribute('visibility', 'hidden');
      return;
    }
    const x = f1(geometry(tl).x(t));
    tl.cursor.setAttribute('x1', x);
    tl.cursor.setAttribute('x2', x);
    tl.cursor.setAttribute('visibility', 'visible');
  }

  function setHover(log, t) {
    log.hoverT = t;
    for (const tl of log.timelines) showCursor(tl, t);
  }

  /** Pointer position over the plot area of a timeline: {x, t}, or null outside it. */
  function plotPoint(tl, ev) {
    const r = tl.svg.getBoundingClientRect();
    const x = ev.clientX - r.left;
    const g = geometry(tl);
    if (x < LABEL_W || x > LABEL_W + g.plotW) return null;
    return { x, y: ev.clientY - r.top, t: g.t0 + (x - LABEL_W) * g.tpp, g };
  }

  function showTip(tl, ev) {
    const p = plotPoint(tl, ev);
    if (!p) {
      hideTip(tl);
      return;
    }
    const { log, part } = tl;
    const t = Math.round(p.t);
    setHover(log, t);
    const res = ticksToMs(log, p.g.tpp);
    let h = `<div class="tip-time"><strong>${esc(fmtOffset(log, t, decimalsFor(res)))}</strong>`;
    const abs = fmtAbsolute(log, t);
    if (abs) h += `<span class="tip-abs">${esc(abs)}</span>`;
    h += '</div><table>';
    const half = (BIN_PX * p.g.tpp) / 2;
    for (const sig of part.signals) {
      const v = valueAt(sig, t);
      const around = upperBound(sig.edges, t + half) - upperBound(sig.edges, t - half);
      const busy = around > 1 ? `<span class="tip-busy">${around} changes here</span>` : '';
      h += `<tr><th>${esc(sig.name)}</th><td class="tip-v${v}">${v}</td><td>${busy}</td></tr>`;
    }
    h += '</table>';
    // The verdict in force, as the diagnosis lane shows it (normal before any change).
    const vi = upperBound(part.verdicts.times, t);
    const v = vi > 0 ? part.verdicts.list[vi - 1] : { verdict: 'normal', labels: [] };
    const labels = Array.isArray(v.labels) ? v.labels.join(', ') : '';
    h += `<div class="tip-verdict v-${verdictClass(v.verdict)}">${esc(v.verdict)}${labels ? ' \u00b7 ' + esc(labels) : ''}</div>`;
    const tip = tl.tip;
    tip.innerHTML = h;
    tip.hidden = false;
    const hr = tl.host.getBoundingClientRect();
    const tw = tip.offsetWidth;
    const th = tip.offsetHeight;
    let left = ev.clientX - hr.left + 14;
    if (left + tw > hr.width) left = ev.clientX - hr.left - tw - 14;
    let top = ev.clientY - hr.top + 14;
    if (top + th > hr.height) top = Math.max(0, ev.clientY - hr.top - th - 10);
    tip.style.left = Math.max(0, left) + 'px';
    tip.style.top = top + 'px';
  }

  function hideTip(tl) {
    tl.tip.hidden = true;
    setHover(tl.log, null);
  }

  // ---------------------------------------------------------------- navigation

  /** A brief ring around what a click brought into view. */
  function flash(el) {
    if (typeof el.animate !== 'function') return;
    if (window.matchMedia && window.matchMedia('(prefers-reduced-motion: reduce)').matches) return;
    el.animate(
      [{ boxShadow: '0 0 0 3px rgba(11, 87, 164, 0.55)' }, { boxShadow: '0 0 0 3px rgba(11, 87, 164, 0)' }],
      { duration: 1600, easing: 'ease-out' }
    );
  }

  function gotoExplanation(id) {
    const el = document.getElementById(id);
    if (!el) return;
    el.scrollIntoView({ block: 'start' });
    flash(el);
  }

  function findHost(logKey, partName) {
    const hosts = document.querySelectorAll('.timeline-host[data-log][data-part]');
    let first = null;
    for (const h of hosts) {
      if (h.dataset.log !== logKey) continue;
      if (!first) first = h;
      if (partName !== undefined && h.dataset.part === partName) return h;
    }
    return first;
  }

  /**
   * Click on anything carrying data-zoom-log/data-zoom-t outside the timelines:
   * focus that log on the instant, and (unless a link inside it takes the reader
   * elsewhere) bring the part's timeline into view.
   */
  function onZoomClick(el, scroll) {
    const log = logs.get(String(el.dataset.zoomLog));
    const t = Number(el.dataset.zoomT);
    if (!log || !isFinite(t)) return false;
    const givenSpan = Number(el.dataset.zoomSpan);
    const span = givenSpan > 0 ? givenSpan : FOCUS_SPAN_NS / log.tickNs;
    centreOn(log, t, span);
    renderLog(log);
    if (!scroll) return true;
    let partName = el.dataset.zoomPart;
    if (partName === undefined) {
      const holder = el.closest('[data-part]');
      if (holder) partName = holder.dataset.part;
    }
    if (partName === undefined) {
      const article = el.closest('article[id]');
      const href = el.getAttribute('href') || '';
      const id = article ? article.id : href.charAt(0) === '#' ? href.slice(1) : '';
      if (id) partName = log.explanationPart.get(id);
    }
    const host = findHost(log.key, partName);
    if (host) {
      host.scrollIntoView({ block: 'center' });
      flash(host);
    }
    return true;
  }

  function wireToolbar(tb, log) {
    log.toolbars.push(tb);
    const names = {
      fit: ['Fit', 'Show the whole log (double-click a timeline)'],
      in: ['Zoom in', 'Zoom in (wheel over a timeline)'],
      out: ['Zoom out', 'Zoom out'],
      left: ['\u2190 Earlier', 'Move earlier (drag a timeline)'],
      right: ['Later \u2192', 'Move later'],
    };
    for (const b of tb.querySelectorAll('button[data-action]')) {
      const n = names[b.dataset.action];
      if (!n) continue;
      if (!b.textContent.trim()) b.textContent = n[0];
      if (!b.title) b.title = n[1];
      if (!b.getAttribute('type')) b.setAttribute('type', 'button');
    }
    tb.addEventListener(
      'click',
      guard((ev) => {
        const b = ev.target.closest('button[data-action]');
        if (!b || !tb.contains(b)) return;
        const { t0, t1 } = log.view;
        const span = t1 - t0;
        const mid = (t0 + t1) / 2;
        switch (b.dataset.action) {
          case 'fit':
            fit(log);
            break;
          case 'in':
            zoomAround(log, mid, 0.5);
            break;
          case 'out':
            zoomAround(log, mid, 2);
            break;
          case 'left':
            setView(log, t0 - span * 0.4, span);
            break;
          case 'right':
            setView(log, t0 + span * 0.4, span);
            break;
          default:
            return;
        }
        renderLog(log);
      })
    );
  }

  function wireTimeline(tl) {
    const { svg, log } = tl;

    svg.addEventListener(
      'wheel',
      guard((ev) => {
        const p = plotPoint(tl, ev);
        if (!p) return; // over the labels, the page scrolls as usual
        ev.preventDefault();
        let dx = ev.deltaX;
        let dy = ev.deltaY;
        const unit = ev.deltaMode === 1 ? 16 : ev.deltaMode === 2 ? 400 : 1;
        dx *= unit;
        dy *= unit;
        if (ev.shiftKey && !dx) {
          dx = dy;
          dy = 0;
        }
        if (Math.abs(dx) > Math.abs(dy)) {
          const span = log.view.t1 - log.view.t0;
          setView(log, log.view.t0 + dx * p.g.tpp, span);
        } else {
          zoomAround(log, p.t, Math.exp(clamp(dy, -300, 300) * 0.002));
        }
        scheduleRender(log);
        showTip(tl, ev);
      }),
      { passive: false }
    );

    svg.addEventListener(
      'pointerdown',
      guard((ev) => {
        if (ev.button !== 0) return;
        const p = plotPoint(tl, ev);
        if (!p) return;
        drag = { tl, x0: ev.clientX, t0: log.view.t0, span: log.view.t1 - log.view.t0, tpp: p.g.tpp, moved: false };
      })
    );

    svg.addEventListener(
      'pointermove',
      guard((ev) => {
        if (!drag) showTip(tl, ev);
      })
    );
    svg.addEventListener(
      'pointerleave',
      guard(() => {
        if (!drag) hideTip(tl);
      })
    );

    svg.addEventListener(
      'click',
      guard((ev) => {
        if (performance.now() < suppressClickUntil) return;
        const goto = ev.target.closest('[data-goto]');
        if (goto) {
          gotoExplanation(goto.getAttribute('data-goto'));
          return;
        }
        const range = ev.target.closest('[data-range]');
        if (range) {
          const [a, b] = range.getAttribute('data-range').split(' ').map(Number);
          const pad = Math.max((b - a) * 0.15, log.minSpan / 2);
          setView(log, a - pad, b - a + 2 * pad);
          renderLog(log);
        }
      })
    );

    svg.addEventListener(
      'dblclick',
      guard((ev) => {
        ev.preventDefault();
        fit(log);
        renderLog(log);
      })
    );

    svg.addEventListener(
      'keydown',
      guard((ev) => {
        const { t0, t1 } = log.view;
        const span = t1 - t0;
        let handled = true;
        if (ev.key === 'ArrowLeft') setView(log, t0 - span * 0.2, span);
        else if (ev.key === 'ArrowRight') setView(log, t0 + span * 0.2, span);
        else if (ev.key === '+' || ev.key === '=') zoomAround(log, (t0 + t1) / 2, 0.5);
        else if (ev.key === '-' || ev.key === '_') zoomAround(log, (t0 + t1) / 2, 2);
        else if (ev.key === '0' || ev.key === 'Home') fit(log);
        else handled = false;
        if (handled) {
          ev.preventDefault();
          renderLog(log);
        }
      })
    );
  }

  function onDragMove(ev) {
    if (!drag) return;
    const dx = ev.clientX - drag.x0;
    if (!drag.moved && Math.abs(dx) < 4) return;
    if (!drag.moved) {
      drag.moved = true;
      drag.tl.tip.hidden = true;
      document.body.classList.add('timeline-dragging');
    }
    const log = drag.tl.log;
    setView(log, drag.t0 - dx * drag.tpp, drag.span);
    scheduleRender(log);
  }

  function onDragEnd() {
    if (!drag) return;
    if (drag.moved) {
      // The click that ends a drag must not also open a marker.
      suppressClickUntil = performance.now() + 250;
      document.body.classList.remove('timeline-dragging');
    }
    drag = null;
  }

  // ---------------------------------------------------------------- page decoration

  /** Verdict colours on the part cards (and summary rows), from the data. */
  function decorate() {
    for (const el of document.querySelectorAll('[data-part][data-log]')) {
      if (el.classList.contains('timeline-host')) continue;
      const log = logs.get(el.dataset.log);
      const part = log && log.parts.get(el.dataset.part);
      if (!part || !part.verdict) continue;
      const cls = verdictClass(part.verdict);
      if (!el.dataset.verdict) el.dataset.verdict = cls;
    }
    // Focus targets reachable from the keyboard (Enter), without changing the
    // role of table rows.
    for (const el of document.querySelectorAll('[data-zoom-log][data-zoom-t]')) {
      if (!el.title) el.title = 'Show on the timeline';
      const interactive = /^(A|BUTTON|INPUT|SELECT|TEXTAREA)$/.test(el.tagName);
      if (!interactive && !el.hasAttribute('tabindex')) el.tabIndex = 0;
      if (!interactive && !/^(TR|TD|TH)$/.test(el.tagName) && !el.hasAttribute('role')) el.setAttribute('role', 'link');
    }
  }

  // ---------------------------------------------------------------- start

  function init() {
    const hosts = Array.from(document.querySelectorAll('.timeline-host[data-log][data-part]'));
    const dataEl = document.getElementById('gardefou-data');
    if (!dataEl) {
      if (hosts.length) throw new Error('no #gardefou-data in the page');
      root.dataset.rendered = String(Math.round(performance.now()));
      return;
    }
    const data = JSON.parse(dataEl.textContent);
    (data.logs || []).forEach((raw, pos) => {
      const log = buildLog(raw, pos);
      logs.set(log.key, log);
    });

    for (const tb of document.querySelectorAll('.timeline-toolbar[data-log]')) {
      const log = logs.get(tb.dataset.log);
      if (log) wireToolbar(tb, log);
    }

    for (const host of hosts) {
      const log = logs.get(host.dataset.log);
      const part = log && log.parts.get(host.dataset.part);
      if (!part) {
        host.innerHTML = '<p class="timeline-missing">No timeline data for this part.</p>';
        continue;
      }
      host.textContent = '';
      const svg = document.createElementNS('http://www.w3.org/2000/svg', 'svg');
      svg.setAttribute('class', 'timeline');
      svg.setAttribute('data-part', part.name);
      svg.setAttribute('data-log', log.key);
      svg.setAttribute('tabindex', '0');
      svg.setAttribute('role', 'img');
      svg.setAttribute(
        'aria-label',
        `Timeline of ${part.name}: signals, verdicts and filter events. ` +
          'Arrows move, + and - zoom, 0 shows the whole log.'
      );
      const tip = document.createElement('div');
      tip.className = 'timeline-tip';
      tip.hidden = true;
      host.appendChild(svg);
      host.appendChild(tip);
      const tl = { log, part, host, svg, tip, width: 0, cursor: null, serial: timelineSerial++, onScreen: true, stale: false };
      log.timelines.push(tl);
      wireTimeline(tl);
    }

    const all = [];
    for (const log of logs.values()) {
      updateRangeText(log);
      all.push(...log.timelines);
    }
    for (const tl of all) tl.width = measureWidth(tl); // one layout for all
    renderAll(all);
    decorate();

    window.addEventListener('pointermove', guard(onDragMove));
    window.addEventListener('pointerup', guard(onDragEnd));
    window.addEventListener('pointercancel', guard(onDragEnd));

    document.addEventListener(
      'click',
      guard((ev) => {
        const el = ev.target.closest && ev.target.closest('[data-zoom-log][data-zoom-t]');
        if (!el || el.closest('svg.timeline')) return;
        // A link inside the element (a summary row's part name, a verdict row's
        // "explanation") keeps its own destination; the timelines still follow.
        const link = ev.target.closest('a[href]');
        const inner = !!link && link !== el && el.contains(link);
        if (onZoomClick(el, !inner) && !inner && el.tagName === 'A') ev.preventDefault();
      })
    );
    document.addEventListener(
      'keydown',
      guard((ev) => {
        if (ev.key !== 'Enter' && ev.key !== ' ') return;
        const el = ev.target.closest && ev.target.closest('[data-zoom-log][data-zoom-t]');
        if (!el || el !== ev.target || /^(A|BUTTON)$/.test(el.tagName)) return;
        ev.preventDefault();
        onZoomClick(el, true);
      })
    );

    // Redraw when the width changes (window resize, scrollbar appearing, print).
    // Redraws wait for the next frame: drawing inside a resize notification could
    // resize again and loop.
    const pending = new Set();
    let resizeFrame = 0;
    const flushResize = guard(() => {
      resizeFrame = 0;
      const tls = Array.from(pending);
      pending.clear();
      for (const tl of tls) renderTimeline(tl);
    });
    const noteWidth = (tl, w) => {
      if (w === tl.width) return;
      tl.width = w;
      pending.add(tl);
      if (!resizeFrame) resizeFrame = requestAnimationFrame(flushResize);
    };
    window.addEventListener(
      'resize',
      guard(() => {
        for (const tl of all) noteWidth(tl, measureWidth(tl));
      })
    );
    if (typeof ResizeObserver === 'function') {
      const byHost = new Map(all.map((tl) => [tl.host, tl]));
      const ro = new ResizeObserver(
        guard((entries) => {
          for (const e of entries) {
            const tl = byHost.get(e.target);
            if (tl) noteWidth(tl, Math.max(360, Math.floor(e.contentRect.width || 960)));
          }
        })
      );
      for (const tl of all) ro.observe(tl.host);
    }
    if (typeof IntersectionObserver === 'function') {
      const byHost = new Map(all.map((tl) => [tl.host, tl]));
      const io = new IntersectionObserver(
        guard((entries) => {
          for (const e of entries) {
            const tl = byHost.get(e.target);
            if (!tl) continue;
            tl.onScreen = e.isIntersecting;
            if (tl.onScreen && tl.stale) {
              pending.add(tl);
              if (!resizeFrame) resizeFrame = requestAnimationFrame(flushResize);
            }
          }
        }),
        { rootMargin: '200px 0px' }
      );
      for (const tl of all) io.observe(tl.host);
    }

    root.dataset.rendered = String(Math.round(performance.now()));
  }

  guard(init)();
})();
