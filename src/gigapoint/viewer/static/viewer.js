// gigapoint viewer client: sends input to the server, draws the JPEG frames it streams back.
// Plain JS, no build step, no external assets.
"use strict";
(function () {
  const $ = (id) => document.getElementById(id);
  const canvas = $("canvas");
  const ctx = canvas.getContext("2d");
  const token = new URLSearchParams(location.search).get("token");
  const withToken = (path, params) => {
    const u = new URL(path, location.href);
    if (token) u.searchParams.set("token", token);
    for (const [k, v] of Object.entries(params || {})) u.searchParams.set(k, v);
    return u;
  };

  const S = {
    ws: null, session: null, cloud: null, schema: [], settings: {}, camera: null,
    seq: 0, sentAt: new Map(), lastFrame: 0, frameTimes: [], fps: null, latency: null, renderTimes: [],
    header: null, fly: false, speedExp: 0, keys: new Set(), pickId: 0, measuring: false, measure: [], measureClosed: false, sectioning: false, section: [],
    pending: { orbit: null, look: null, pan: null, zoom: null }, retry: 0, classes: null, classesAsked: -1e9, classesTimer: null,
  };
  window.gigapoint = S; // for tests and the curious

  // ---------------------------------------------------------------- connection
  function deviceSize() {
    const r = canvas.getBoundingClientRect();
    const dpr = Math.min(window.devicePixelRatio || 1, 2);
    // one factor for both sides: each capped at 4096 on its own stretched a wide view (a 5K screen's)
    const k = dpr * Math.min(1, 4096 / Math.max(r.width * dpr, r.height * dpr, 1));
    return [Math.max(1, Math.min(4096, Math.round(r.width * k))), Math.max(1, Math.min(4096, Math.round(r.height * k)))];
  }

  function connect() {
    const [w, h] = deviceSize();
    const u = withToken("ws", { w, h });
    u.protocol = location.protocol === "https:" ? "wss:" : "ws:";
    const ws = new WebSocket(u);
    ws.binaryType = "arraybuffer";
    S.ws = ws;
    let opened = false;
    ws.onopen = () => { opened = true; S.retry = 0; status("connected"); sendResize(true); };
    ws.onmessage = (ev) => (typeof ev.data === "string" ? onJson(JSON.parse(ev.data)) : onFrame(ev.data));
    ws.onclose = () => {
      S.ws = null;
      S.retry = Math.min(S.retry + 1, 10);
      // the picture and the HUD stay as the server last sent them: dimmed, so they do not pass for live
      canvas.classList.add("stale");
      status(opened ? "disconnected — reconnecting…" : `no answer from the viewer server (stopped? or a proxy that does not pass WebSockets) — retrying every ${(0.3 * S.retry).toFixed(1)} s`);
      setTimeout(connect, 300 * S.retry);
    };
  }

  function send(msg, trackLatency) {
    if (!S.ws || S.ws.readyState !== WebSocket.OPEN) return;
    if (trackLatency) {
      msg.seq = ++S.seq;
      S.sentAt.set(S.seq, performance.now());
      if (S.sentAt.size > 500) S.sentAt.delete(S.sentAt.keys().next().value);
    }
    S.ws.send(JSON.stringify(msg));
  }

  function status(text) { $("status").textContent = text; }
  let errorTimer = null;
  let errorFrom = null;  // the message type the shown error replied to: a valid setting clears a setting's error
  function showError(text, from = null) {
    const e = $("error");
    e.textContent = text;
    e.classList.remove("hidden");
    errorFrom = from;
    clearTimeout(errorTimer);
    errorTimer = setTimeout(() => e.classList.add("hidden"), 5000);
  }

  function showCloud(cloud) {
    S.cloud = cloud;
    // the fly speed follows the cloud's size as it grows (a loading or live cloud's: its hello held a first slice, or nothing)
    const b = cloud.bounds;
    S.sceneRadius = Math.hypot(b[1][0] - b[0][0], b[1][1] - b[0][1], b[1][2] - b[0][2]) / 2 || 1;
    updateSpeedLabel();
    const info = $("cloudinfo");  // "name · N points · M batches": a count and its unit never split over lines
    info.textContent = `${cloud.name} · `;
    for (const [i, part] of [`${cloud.points.toLocaleString()} points`, `${cloud.batches.toLocaleString()} batch${cloud.batches === 1 ? "" : "es"}`].entries()) {
      const span = document.createElement("span");
      span.className = "nowrap";
      span.textContent = part;
      info.append(...(i ? [" · ", span] : [span]));
    }
  }

  function onJson(m) {
    if (m.type === "hello") {
      // a reconnect to the same cloud (the server restarted, the network dropped) keeps this tab's view and settings
      const same = S.cloud && S.cloud.name === m.cloud.name && JSON.stringify(S.cloud.bounds) === JSON.stringify(m.cloud.bounds);
      const kept = same && S.camera ? { camera: S.camera, settings: S.settings, measure: S.measure, closed: S.measureClosed, section: S.section } : null;
      drawing = 0;  // the new session numbers its frames from 1: the old count dropped them all
      S.session = m.session; S.schema = m.schema; S.settings = m.settings; S.camera = m.camera;
      showCloud(m.cloud);
      showClasses(m.classes);
      showMeasure({ points: [], segments: [] });  // a new session measures nothing yet (a reconnect's points are sent back below)
      // the new session has no section line: a reconnect's is sent back (with the width the panel kept) and drawn again
      if (S.sectioning) startSection(kept ? kept.section : []);
      buildSettings();
      updateSpeedLabel();
      setFov(m.camera.fov, false);
      canvas.classList.remove("stale");
      status("connected — drawing the view…");  // the first frame can take seconds (a big cloud, a first run's compile)
      S.awaitingFrame = true;
      sendQuality();  // the panel's values, which a reload or a reconnect kept, not the new session's defaults
      if (kept) {
        send({ type: "camera", ...kept.camera }, true);
        const changed = Object.fromEntries(Object.entries(kept.settings).filter(([k, v]) => JSON.stringify(v) !== JSON.stringify(m.settings[k])));
        if (Object.keys(changed).length) send({ type: "settings", values: changed }, true);
        // the measurement too, in world coordinates; 100 points a message stays under the message limit
        // (the last batch closes a closed one again)
        for (let i = 0; i < kept.measure.length; i += 100) {
          const last = i + 100 >= kept.measure.length;
          send({ type: "measure", action: "restore", points: kept.measure.slice(i, i + 100), ...(last && kept.closed ? { closed: true } : {}) }, true);
        }
      }
    } else if (m.type === "classes") {
      showClasses(m);
    } else if (m.type === "settings") {
      S.settings = m.values;
      syncSettings();
      syncClasses();
      if (errorFrom === "settings") $("error").classList.add("hidden");  // the last change was taken
    } else if (m.type === "pick") {
      showPick(m);
    } else if (m.type === "measure") {
      showMeasure(m);
    } else if (m.type === "volume") {
      showVolume(m);
    } else if (m.type === "volume_result") {
      showVolumeResult(m);
    } else if (m.type === "section") {
      showSection(m);
    } else if (m.type === "section_result") {
      showSectionResult(m);
    } else if (m.type === "error") {
      showError(m.message, m.in_reply_to);
      if (m.in_reply_to === "settings") { syncSettings(); syncClasses(); } // the panels show what the server kept
    }
  }

  // ---------------------------------------------------------------- frames
  let drawing = 0;
  function onFrame(buf) {
    const dv = new DataView(buf);
    const n = dv.getUint32(4, true);
    const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 8, n)));
    if (header.cloud) showCloud(header.cloud);  // sent again when it changed (a live or loading cloud), whether or not this image is drawn
    // an octree's list grows with the classes of the nodes loaded, a loading cloud's with those of its points, a
    // swapped cloud has its own: asked again
    if (header.cloud || (header.full && S.classes && !S.classes.complete)) askClasses();
    const blob = new Blob([new Uint8Array(buf, 8 + n)], { type: "image/jpeg" });
    const now = performance.now();
    if (header.seq != null && S.sentAt.has(header.seq)) {
      S.latency = now - S.sentAt.get(header.seq);
      for (const k of S.sentAt.keys()) { if (k <= header.seq) S.sentAt.delete(k); else break; }
    }
    createImageBitmap(blob).then((bmp) => {
      if (header.frame < drawing) { bmp.close(); return; }
      drawing = header.frame;
      const [w, h] = deviceSize();
      if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
      ctx.imageSmoothingEnabled = header.full;
      ctx.drawImage(bmp, 0, 0, canvas.width, canvas.height);
      bmp.close();
      S.header = header; S.camera = header.camera; S.lastFrame = header.frame;
      if (S.awaitingFrame) { S.awaitingFrame = false; status("connected"); }
      S.frameTimes.push(performance.now());
      S.renderTimes.push(header.render_ms);  // the profiler line: the last 100 frames
      if (S.renderTimes.length > 100) S.renderTimes.shift();
      canvas.dataset.frame = String(header.frame);
      canvas.dataset.full = String(header.full);
      updateStats();
      if (Math.abs(S.camera.fov - Number($("fov").value)) > 0.5 && document.activeElement !== $("fov")) setFov(S.camera.fov, false);
    }).catch((e) => showError("cannot decode frame: " + e));
  }

  function fmtBytes(b) { return b > 1 << 30 ? (b / (1 << 30)).toFixed(2) + " GiB" : (b / (1 << 20)).toFixed(0) + " MiB"; }
  function updateStats() {
    const h = S.header; if (!h) return;
    const now = performance.now();
    while (S.frameTimes.length && now - S.frameTimes[0] > 1000) S.frameTimes.shift();
    // the rate of the frames of the last second; idle (no new frame), the last rate measured, or nothing
    const n = S.frameTimes.length;
    if (n >= 2) S.fps = (n - 1) * 1000 / Math.max(S.frameTimes[n - 1] - S.frameTimes[0], 1);
    // the latency too: idle, the one measured last is marked as such, not shown as now's
    const rates = [...(S.fps == null ? [] : [`fps ${S.fps.toFixed(0)}`]), ...(S.latency == null ? [] : [`latency ${S.latency.toFixed(0)} ms`])];
    const lines = [
      n >= 2 ? rates.join("   ") : rates.length ? `idle (last ${rates.join(", ")})` : "idle",
      `frame ${h.render_ms.toFixed(1)} ms render + ${h.encode_ms.toFixed(1)} ms jpeg`,
      `last ${S.renderTimes.length}: avg ${(S.renderTimes.reduce((a, b) => a + b, 0) / Math.max(S.renderTimes.length, 1)).toFixed(1)} ms, worst ${Math.max(0, ...S.renderTimes).toFixed(1)} ms`,
      `${h.width}×${h.height}${h.full ? "" : "  (1/" + h.scale + " while moving)"}`,
      `points ${h.points.toLocaleString()} / ${h.points_total.toLocaleString()}`,
      `batches ${h.batches.toLocaleString()} / ${h.batches_total.toLocaleString()}`,
      `memory ${fmtBytes(h.memory)}   loaded ${(h.load_progress * 100).toFixed(0)}%   ${h.backend}`,
      ...(h.cloud_bytes ? [`cloud data ${fmtBytes(h.cloud_bytes)}, ${(h.cloud_bytes / Math.max(h.points_total, 1)).toFixed(1)} B a point`] : []),
    ];
    if (h.note) lines.push(h.note);  // e.g. the preview of a conversion still running
    $("stats").textContent = lines.join("\n");
  }
  setInterval(updateStats, 500);

  // ---------------------------------------------------------------- settings panel (from the server's schema)
  function toHex(c) { return "#" + c.slice(0, 3).map((v) => v.toString(16).padStart(2, "0")).join(""); }
  function buildSettings() {
    const form = $("settings");
    form.textContent = "";
    for (const f of S.schema) {
      if (f.kind === "classes") continue;  // hidden_classes: the Classes panel's
      const row = document.createElement("label");
      row.className = "row";
      row.title = f.help || "";
      let input;
      if (f.kind === "bool") {
        input = document.createElement("input"); input.type = "checkbox";
        row.append(input, " " + f.label);
      } else {
        row.append(f.label + " ");
        if (f.kind === "enum") {
          input = document.createElement("select");
          for (const c of f.choices) { const o = document.createElement("option"); o.value = JSON.stringify(c); o.textContent = String(c); input.append(o); }
        } else if (f.kind === "color") {
          input = document.createElement("input"); input.type = "color";
        } else if (f.kind === "range") {
          input = document.createElement("span"); input.className = "range-pair";
          for (let i = 0; i < 2; i++) { const e = document.createElement("input"); e.type = "number"; e.step = "any"; e.placeholder = i ? "high" : "low"; input.append(e); }
        } else if (f.kind === "int" || f.kind === "float") {
          input = document.createElement("input"); input.type = "number";
          input.step = f.step || (f.kind === "int" ? "1" : "any");
          if (f.min != null) input.min = f.min;
          if (f.max != null) input.max = f.max;
          // a bounded float with a step (opacity) is a slider
          if (f.kind === "float" && f.min != null && f.max != null && f.step && !f.nullable) input.type = "range";
          if (f.nullable) input.placeholder = "auto";
        } else {
          input = document.createElement("input"); input.type = "text";
          if (f.name === "color_attribute") {  // the cloud's attributes offered as one types
            const list = document.createElement("datalist"); list.id = "attribute-names";
            for (const a of S.cloud.attributes || []) { const o = document.createElement("option"); o.value = a; list.append(o); }
            input.setAttribute("list", list.id); row.append(list);
          }
        }
        row.append(input);
      }
      input.dataset.name = f.name;
      input.id = "setting-" + f.name;
      input.addEventListener("change", () => onSettingChange(f, input));
      form.append(row);
    }
    syncSettings();
  }

  function syncSettings() {
    for (const f of S.schema) {
      const input = $("setting-" + f.name); if (!input) continue;
      const v = S.settings[f.name];
      input.classList?.remove("invalid");
      if (f.kind === "bool") input.checked = !!v;
      else if (f.kind === "enum") input.value = JSON.stringify(v);
      else if (f.kind === "color") input.value = toHex(v);
      else if (f.kind === "range") { const [a, b] = input.querySelectorAll("input"); a.value = v ? v[0] : ""; b.value = v ? v[1] : ""; a.classList.remove("invalid"); b.classList.remove("invalid"); }
      else input.value = v == null ? "" : String(v);
    }
  }

  function onSettingChange(f, input) {
    let v;
    if (f.kind === "bool") v = input.checked;
    else if (f.kind === "enum") v = JSON.parse(input.value);
    else if (f.kind === "color") { const a = (S.settings[f.name] || [0, 0, 0, 255])[3]; v = [1, 3, 5].map((i) => parseInt(input.value.slice(i, i + 2), 16)).concat([a]); }
    else if (f.kind === "range") {
      const [a, b] = input.querySelectorAll("input");
      if (a.value === "" && b.value === "") v = null;
      else if (a.value === "" || b.value === "") {  // half a range: nothing sent, so say what is missing
        const empty = a.value === "" ? a : b;
        empty.classList.add("invalid");
        showError(`${f.label}: give both low and high (both empty: the default)`, "settings");
        return;
      } else v = [Number(a.value), Number(b.value)];
    } else if (f.kind === "int" || f.kind === "float") {
      if (input.value === "") { if (!f.nullable) { input.classList.add("invalid"); return; } v = null; }
      else { v = Number(input.value); if (!Number.isFinite(v)) { input.classList.add("invalid"); return; } }
    } else v = input.value;
    send({ type: "settings", values: { [f.name]: v } }, true);
  }

  // ---------------------------------------------------------------- the Classes panel (hidden_classes: the classes unticked)
  function showClasses(c) {
    S.classes = c;
    const list = $("classes"), panel = $("classes-panel");
    list.textContent = "";
    for (const k of c.classes) {
      const row = document.createElement("label");
      row.className = "row";
      row.title = `class ${k.code}: ${k.name}`;
      const box = document.createElement("input");
      box.type = "checkbox"; box.dataset.code = String(k.code); box.disabled = !c.enabled;
      box.addEventListener("change", () => sendHidden(listedCodes().filter((code) => !list.querySelector(`input[data-code="${code}"]`).checked)));
      const swatch = document.createElement("span");
      swatch.className = "swatch"; swatch.style.background = k.color;  // (the classification colour mode's colour)
      const code = document.createElement("span");
      code.className = "code"; code.textContent = String(k.code);
      row.append(box, swatch, code, " " + k.name);
      list.append(row);
    }
    panel.classList.toggle("disabled", !c.enabled);
    panel.title = c.reason || "";
    for (const b of ["btn-classes-all", "btn-classes-none"]) $(b).disabled = !c.enabled;
    $("classes-note").textContent = c.enabled ? (c.classes.length ? "" : "no class in this cloud") : c.reason;
    syncClasses();
  }

  // at most every 2 s; a change within them is asked for once they are past (the last points of a load
  // brought a class the list then missed, for good: no frame came after them to ask again)
  function askClasses() {
    if (S.classesTimer) return;
    S.classesTimer = setTimeout(() => {
      S.classesTimer = null;
      S.classesAsked = performance.now();
      send({ type: "classes" });
    }, Math.max(0, S.classesAsked + 2000 - performance.now()));
  }

  function listedCodes() { return S.classes ? S.classes.classes.map((k) => k.code) : []; }
  // the set sent: the listed classes as ticked, and hidden classes the list does not show, kept hidden
  function sendHidden(unticked) {
    const listed = new Set(listedCodes());
    const kept = (S.settings.hidden_classes || []).filter((code) => !listed.has(code));
    send({ type: "settings", values: { hidden_classes: [...kept, ...unticked].sort((a, b) => a - b) } }, true);
  }

  function syncClasses() {
    const hidden = new Set(S.settings.hidden_classes || []);
    for (const box of $("classes").querySelectorAll("input[data-code]")) box.checked = !hidden.has(Number(box.dataset.code));
  }

  $("btn-classes-all").addEventListener("click", () => send({ type: "settings", values: { hidden_classes: [] } }, true));
  $("btn-classes-none").addEventListener("click", () => sendHidden(listedCodes()));

  // ---------------------------------------------------------------- picking
  function showPick(m) {
    const box = $("pickinfo");
    if (!m.found) { box.textContent = "no point here"; box.classList.remove("hidden"); return; }
    const i = m.info;
    // coordinates as the server sends them: a file's points rounded to its scale (PointCloud.point_info)
    // an octree's entries have no index: what was picked, a point or (a progressive octree's inner node) a voxel
    const what = [i.voxel ? "voxel" : "point", ...(i.index == null ? [] : ["#" + i.index])].join(" ");
    const lines = [`${what}${m.pivot ? "  (new pivot)" : ""}`, `x ${String(i.position[0])}`, `y ${String(i.position[1])}`, `z ${String(i.position[2])}`];
    if (i.rgba) lines.push(`rgba ${i.rgba.join(", ")}${i.rgba_approx ? ` (approx.: ${i.rgba_approx})` : ""}`);
    for (const [k, v] of Object.entries(i)) if (!["index", "position", "rgba", "rgba_approx", "voxel"].includes(k)) lines.push(`${k} ${Array.isArray(v) ? v.join(", ") : v}`);
    box.textContent = lines.join("\n");
    box.dataset.index = String(i.index);
    box.classList.remove("hidden");
  }

  // ---------------------------------------------------------------- measuring (the server draws the polyline into the frames)
  function setMeasuring(on) {
    if (on && S.sectioning) setSectioning(false);  // one tool's clicks at a time
    if (S.measuring && !on) { send({ type: "measure", action: "clear" }, true); S.measure = []; }  // (its reply is not shown)
    S.measuring = on;
    $("btn-measure").classList.toggle("active", on);
    canvas.classList.toggle("measuring", on);
    $("measureinfo").classList.toggle("hidden", !on);
    $("volume-panel").classList.toggle("hidden", !on);
    if (on) showMeasure({ points: [], segments: [] });
  }

  // the units of the measured numbers (io.crs_units of the cloud's CRS, in the reply and hello's cloud): a line saying them
  function unitsLine(u) {
    const h = u.horizontal, v = u.vertical;
    const heights = v ? `heights in ${v.symbol}` : "heights in unknown units";
    if (!h) return v ? `x, y in unknown units (no 3D or horizontal unit); ${heights}` : "units unknown (the cloud names no CRS unit)";
    if (h.metres == null) return `x, y in ${h.name}s (a geographic CRS): no 3D or horizontal length; ${heights}`;
    if (u.vertical_assumed) return `units: ${h.symbol} (heights taken as ${h.symbol}: the CRS names no vertical unit)`;
    return v.symbol === h.symbol ? `units: ${h.symbol}` : `units: ${h.symbol}, ${heights} (the 3D length in ${h.symbol})`;
  }

  function showMeasure(m) {
    if (!S.measuring) return;  // the reply to the clear that ended it
    S.measure = m.points;  // kept for a reconnect: its new session gets them back
    const u = m.units || (S.cloud && S.cloud.units) || {};
    const h = u.horizontal && u.horizontal.metres != null ? u.horizontal : null, v = u.vertical;  // (degrees: no length unit)
    // lengths to the decimals of the positions (a file's points come at its scale: 0.01 m -> 2), 2 to 3
    const dec = Math.max(2, Math.min(3, ...m.points.flat().map((x) => (String(x).split(".")[1] || "").length)));
    // a number with its unit ("—": not a length, degrees); in metres too where asked and its unit is another (a surveyor's metric plans)
    const f = (x, unit, metric = false, sign = "") => {
      if (x == null) return "—";
      const shown = `${sign}${x.toFixed(dec)}${unit ? " " + unit.symbol : ""}`;
      return metric && unit && unit.metres !== 1 ? `${shown} (${sign}${(x * unit.metres).toFixed(dec)} m)` : shown;
    };
    const dz = (x, metric) => f(x, v, metric, x >= 0 ? "+" : "");
    const lines = ["measure: 3D, horizontal, height", unitsLine(u)];
    m.segments.forEach((s, i) => lines.push(`${i + 1}: ${f(s.length, h)}   horizontal ${f(s.horizontal, h)}   height ${dz(s.vertical)}`));
    if (m.segments.length) lines.push(`total ${f(m.total.length, h, true)}   horizontal ${f(m.total.horizontal, h, true)}   height ${dz(m.total.vertical, true)}`);
    if (m.crossing) lines.push(m.crossing);  // (a bow tie: no area, no volume)
    else if (m.closed) {  // (area null: degrees, no area)
      const area = m.area == null ? "—" : `${m.area.toFixed(dec)}${h ? ` ${h.symbol}²` : ""}${h && h.metres !== 1 ? ` (${(m.area * h.metres * h.metres).toFixed(dec)} m²)` : ""}`;
      lines.push(`polygon: area ${area}   perimeter ${f(m.perimeter, h, true)}`);
    }
    if (m.points.length < 2) lines.push(m.points.length ? "1 point: click the next" : "click a point to start");
    if (m.message) lines.push(m.message);  // a click on empty sky
    lines.push(`Backspace removes the last point${m.points.length >= 3 ? ` · C ${m.closed ? "opens the polygon" : "closes the polygon: its area, its volume"}` : ""} · Esc or M ends`);
    $("measureinfo").textContent = lines.join("\n");
    $("measureinfo").dataset.points = String(m.points.length);
    $("measureinfo").dataset.closed = String(!!m.closed);
    S.measureClosed = !!m.closed;
    $("btn-measure-close").disabled = m.points.length < 3;
    $("btn-measure-close").textContent = m.closed ? "open polygon" : "close polygon";
    $("btn-measure-close").classList.toggle("active", !!m.closed);
    $("btn-volume").disabled = !m.closed || !!m.crossing;
    $("volume-unit").textContent = lengthUnit().trim();
    if (!m.message) showVolumeInfo(m.crossing || (m.closed ? "volume: the stockpile volume inside the polygon" : "close the polygon (C) for its area and volume"), false);
  }

  function closePolygon() {
    if (S.measure.length >= 3) send({ type: "measure", action: S.measureClosed ? "open" : "close" }, true);
  }

  // ---------------------------------------------------------------- the volume inside the closed measurement (the server computes it: gp.volume)
  function showVolumeInfo(text, copyable) {
    $("volume-info").textContent = text;
    $("btn-volume-copy").disabled = !copyable;
  }

  function requestVolume() {
    const choice = $("volume-base").value, gsd = Number($("volume-gsd").value), z = Number($("volume-elevation").value);
    if (choice === "elevation" && ($("volume-elevation").value === "" || !Number.isFinite(z))) { $("volume-elevation").classList.add("invalid"); return; }
    $("volume-elevation").classList.remove("invalid");
    const base = choice === "elevation" ? z : choice;
    send({ type: "volume", base, ...($("volume-gsd").value !== "" && gsd > 0 ? { gsd } : {}), id: ++S.pickId });
  }

  function showVolume(m) {
    if (!S.measuring) return;
    showVolumeInfo(`computing the volume on a grid of ${m.gsd}…`, false);
  }

  function showVolumeResult(m) {
    if (!S.measuring) return;  // (the server sends none for a polygon changed since)
    const info = $("volume-info");
    if (m.error) { showVolumeInfo(m.error, false); return; }
    const u = m.units, n = (x) => x.toLocaleString(undefined, { minimumFractionDigits: 2, maximumFractionDigits: 2 });
    const b = m.base, length = u.length === "units" ? "" : ` ${u.length}`;
    const base = b.type === "plane"
      ? `plane through the toe, mean z ${n(b.z)}${length}, slope ${(Math.hypot(...b.slope) * 100).toFixed(2)} % (dz/dx ${b.slope[0].toFixed(4)}, dz/dy ${b.slope[1].toFixed(4)}), toe rms ${n(b.boundary_rms)}${length}`
      : b.type === "lowest" ? `flat at the toe's lowest, z ${n(b.z)}${length}` : `flat at z ${n(b.z)}${length}`;
    const pct = (x) => `${(x * 100).toFixed(1)} %`;
    showVolumeInfo([
      `fill ${n(m.fill)} ${u.volume}`,
      `cut  ${n(m.cut)} ${u.volume}`,
      `net  ${n(m.net)} ${u.volume}`,
      `base ${base}`,
      `footprint ${n(m.area)} ${u.area} (the polygon ${n(m.polygon_area)} ${u.area})`,
      `highest z ${n(m.highest[2])}${length}, ${n(m.height)}${length} above the base`,
      `filled ${pct(m.filled)} of the pixels by interpolation${m.empty ? `, ${pct(m.empty)} left empty (no volume)` : ""}`,
      m.gsd_note,
      ...(m.note ? [m.note] : []),  // (thinned points: a polygon round much of a large cloud)
      ...m.warnings.map((w) => `warning: ${w}`),  // (a toe beyond the data: why pixels are empty, how to mend it)
    ].join("\n"), true);
    info.dataset.fill = String(m.fill);
  }

  function copyVolume() {
    const text = $("volume-info").textContent;
    if (navigator.clipboard) navigator.clipboard.writeText(text).catch(() => {});
    else { const r = document.createRange(); r.selectNodeContents($("volume-info")); getSelection().removeAllRanges(); getSelection().addRange(r); }
  }

  // ---------------------------------------------------------------- the section tool (the server computes the section, draws the line)
  function setSectioning(on) {
    if (on && S.measuring) setMeasuring(false);
    if (S.sectioning && !on) send({ type: "section", action: "clear" }, true);
    if (!on) $("section-overlay").classList.add("hidden");
    S.sectioning = on;
    $("btn-section").classList.toggle("active", on);
    canvas.classList.toggle("sectioning", on);
    $("section-panel").classList.toggle("hidden", !on);
    if (on) startSection();
  }

  const sectionEnlarged = () => !$("section-overlay").classList.contains("hidden");

  // the size the server draws the section at: the box it is shown in (the panel's, or the enlarged one over the view), in device pixels
  function sectionImageSize() {
    const dpr = Math.min(window.devicePixelRatio || 1, 2), box = $("section-large-box");
    const [w, h] = sectionEnlarged() ? [box.clientWidth, box.clientHeight] : [$("section-image").parentElement.clientWidth || 270, 160];
    return [w, h].map((v) => Math.max(8, Math.min(2048, Math.round(v * dpr))));
  }

  // the width as typed, or the server's first (1/50 of the cloud); ``line``: a lost connection's two points, drawn again
  function startSection(line = []) {
    const width = Number($("section-width").value);
    const points = line.length === 2 ? { points: line } : {};
    send({ type: "section", action: "set", size: sectionImageSize(), ...($("section-width").value !== "" && width > 0 ? { width } : {}), ...points }, true);
    if (points.points) return;  // the last image stays until the new session's arrives
    $("section-image").classList.add("hidden");
    $("btn-section-csv").disabled = true;
    $("btn-section-enlarge").disabled = true;
    $("section-overlay").classList.add("hidden");
    $("section-info").textContent = "click the line's first end";
  }

  // enlarged: drawn again at the overlay's size (a small image stretched is a blur); closed: at the panel's again
  function enlargeSection(on) {
    if (on === sectionEnlarged()) return;
    $("section-overlay").classList.toggle("hidden", !on);
    send({ type: "section", action: "set", size: sectionImageSize() }, true);
  }

  function lengthUnit() {  // the symbol lengths are in ("" where the cloud names none, or its x, y are degrees)
    const h = S.cloud && S.cloud.units && S.cloud.units.horizontal;
    return h && h.metres != null ? " " + h.symbol : "";
  }

  function showSection(m) {
    if (!S.sectioning) return;  // the reply to the clear that ended it
    S.section = m.points;  // kept for a reconnect: its new session draws the line again
    $("section-width").value = String(m.width);
    $("section-unit").textContent = lengthUnit().trim();
    const info = $("section-info");
    info.dataset.points = String(m.points.length);
    if (m.computing) info.textContent = "computing the section…";
    else info.textContent = m.points.length ? "click the line's other end" : "click the line's first end";
    if (m.message) info.textContent += ` (${m.message})`;
  }

  function showSectionResult(m) {
    if (!S.sectioning) return;
    const info = $("section-info"), img = $("section-image");
    if (m.error) {
      info.textContent = m.error; img.classList.add("hidden"); $("btn-section-csv").disabled = true; $("btn-section-enlarge").disabled = true;
      $("section-overlay").classList.add("hidden");
      return;
    }
    const u = lengthUnit(), n = (x) => x.toFixed(2);
    img.src = m.image;
    img.classList.remove("hidden");
    $("section-large").src = m.image;
    $("section-large-info").textContent = `${m.count.toLocaleString()} points · length ${n(m.length)}${u} · width ${n(m.width)}${u} · heights ${n(m.z[0])} to ${n(m.z[1])}${u}`;
    $("btn-section-enlarge").disabled = false;
    info.textContent = [
      `${m.count.toLocaleString()} points · length ${n(m.length)}${u} · width ${n(m.width)}${u}`,
      `heights ${n(m.z[0])} to ${n(m.z[1])}${u} (${n(m.z[1] - m.z[0])}${u})`,
      unitsLine(m.units || {}),
      ...(m.message ? [m.message] : []),
      "click two points for another line · Esc ends",
    ].join("\n");
    info.dataset.count = String(m.count);
    $("btn-section-csv").disabled = false;
  }

  function relPos(ev) {
    const r = canvas.getBoundingClientRect();
    return [Math.min(1, Math.max(0, (ev.clientX - r.left) / r.width)), Math.min(1, Math.max(0, (ev.clientY - r.top) / r.height))];
  }

  // ---------------------------------------------------------------- mouse and touch
  const pointers = new Map();
  let drag = null; // {mode, x, y, moved}
  let pinch = null; // {dist, cx, cy}
  const viewHeight = () => canvas.getBoundingClientRect().height || 1;

  function queue(kind, a, b) {
    const p = S.pending;
    if (kind === "zoom") { p.zoom = p.zoom ? { factor: p.zoom.factor * a, x: b[0], y: b[1] } : { factor: a, x: b[0], y: b[1] }; }
    else if (p[kind]) { p[kind][0] += a; p[kind][1] += b; } else p[kind] = [a, b];
  }

  canvas.addEventListener("contextmenu", (e) => e.preventDefault());
  canvas.addEventListener("pointerdown", (e) => {
    canvas.focus();
    canvas.setPointerCapture(e.pointerId);
    pointers.set(e.pointerId, [e.clientX, e.clientY]);
    if (e.pointerType === "touch") {
      if (pointers.size === 2) { drag = null; pinch = pinchState(); }
      else if (pointers.size === 1) drag = { mode: "orbit", x: e.clientX, y: e.clientY, moved: 0 };
      return;
    }
    const pan = e.button === 2 || e.button === 1 || (e.button === 0 && e.shiftKey);
    drag = { mode: pan ? "pan" : S.fly ? "look" : "orbit", x: e.clientX, y: e.clientY, moved: 0, button: e.button };
    canvas.classList.add("dragging");
  });
  canvas.addEventListener("pointermove", (e) => {
    if (!pointers.has(e.pointerId)) return;
    pointers.set(e.pointerId, [e.clientX, e.clientY]);
    if (pinch && pointers.size >= 2) {
      const p = pinchState();
      const h = viewHeight();
      queue("zoom", pinch.dist / Math.max(p.dist, 1), relPos({ clientX: p.cx, clientY: p.cy }));
      queue("pan", (p.cx - pinch.cx) / h, (p.cy - pinch.cy) / h);
      pinch = p;
      return;
    }
    if (!drag) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag.x = e.clientX; drag.y = e.clientY; drag.moved += Math.abs(dx) + Math.abs(dy);
    const h = viewHeight();
    if (drag.mode === "pan") queue("pan", dx / h, dy / h);
    else if (drag.mode === "look") queue("look", (dx / h) * 90, (dy / h) * 90);
    else queue("orbit", (-dx / h) * 240, (dy / h) * 180);
  });
  function endPointer(e) {
    pointers.delete(e.pointerId);
    canvas.classList.remove("dragging");
    if (drag && drag.moved < 4 && e.type === "pointerup" && (drag.button === 0 || e.pointerType === "touch")) {
      const [x, y] = relPos(e);
      if (S.sectioning) send({ type: "section", action: "add", x, y, id: ++S.pickId }, true);
      else if (S.measuring) send({ type: "measure", action: "add", x, y, id: ++S.pickId }, true);
      else send({ type: "pick", x, y, id: ++S.pickId });
    }
    if (pointers.size < 2) pinch = null;
    drag = null;
    if (pointers.size === 1 && [...pointers.values()][0]) { const [x, y] = [...pointers.values()][0]; drag = { mode: "orbit", x, y, moved: 99 }; }
  }
  canvas.addEventListener("pointerup", endPointer);
  canvas.addEventListener("pointercancel", endPointer);
  function pinchState() {
    const [a, b] = [...pointers.values()];
    return { dist: Math.hypot(a[0] - b[0], a[1] - b[1]), cx: (a[0] + b[0]) / 2, cy: (a[1] + b[1]) / 2 };
  }
  canvas.addEventListener("dblclick", (e) => {
    if (S.measuring || S.sectioning) return;  // their clicks pick points: no pivot
    const [x, y] = relPos(e);
    send({ type: "pick", x, y, pivot: true, id: ++S.pickId }, true);
  });
  canvas.addEventListener("wheel", (e) => {
    e.preventDefault();
    const unit = e.deltaMode === 1 ? 33 : e.deltaMode === 2 ? 400 : 1;
    const factor = Math.exp(Math.max(-300, Math.min(300, e.deltaY * unit)) * 0.0015);
    queue("zoom", factor, relPos(e));
  }, { passive: false });

  // ---------------------------------------------------------------- keyboard: fly with WASD / QE
  const typing = () => ["INPUT", "SELECT", "TEXTAREA"].includes(document.activeElement?.tagName);
  window.addEventListener("keydown", (e) => {
    if (typing() || e.ctrlKey || e.metaKey || e.altKey) return;
    const k = e.key.toLowerCase();
    if ("wasdqe".includes(k) && k.length === 1) { S.keys.add(k); e.preventDefault(); }
    else if (k === "f") setFly(!S.fly);
    else if (k === "m") setMeasuring(!S.measuring);
    else if (k === "escape" && sectionEnlarged()) enlargeSection(false);  // the first Esc closes the enlarged section, the next ends the tool
    else if (k === "escape" && S.sectioning) setSectioning(false);
    else if (k === "escape" && S.measuring) setMeasuring(false);
    else if (k === "c" && S.measuring) closePolygon();
    else if (k === "backspace" && S.measuring) { e.preventDefault(); send({ type: "measure", action: "undo" }, true); }
    else if (k === "r") send({ type: "reset" }, true);
    else if (k >= "1" && k <= "5") send({ type: "view", name: ["top", "front", "side", "iso", "auto"][Number(k) - 1] }, true);
    else if (k === "+" || k === "=") adjustSpeed(0.5);
    else if (k === "-") adjustSpeed(-0.5);
  });
  window.addEventListener("keyup", (e) => S.keys.delete(e.key.toLowerCase()));
  window.addEventListener("blur", () => S.keys.clear());

  function flySpeed() { return (S.sceneRadius || 1) * 0.25 * Math.pow(2, S.speedExp); }
  function updateSpeedLabel() { $("speed-value").textContent = `${flySpeed().toPrecision(3)}/s`; }
  function adjustSpeed(d) { S.speedExp = Math.max(-4, Math.min(4, S.speedExp + d)); $("speed").value = S.speedExp; updateSpeedLabel(); }
  function setFly(on) { S.fly = on; $("fly").checked = on; }

  // ---------------------------------------------------------------- per animation frame: flush input
  let lastTick = performance.now();
  function tick(now) {
    const dt = Math.min(0.1, (now - lastTick) / 1000);
    lastTick = now;
    const p = S.pending;
    if (p.orbit) { send({ type: "orbit", dyaw: p.orbit[0], dpitch: p.orbit[1] }, true); p.orbit = null; }
    if (p.look) { send({ type: "look", dyaw: p.look[0], dpitch: p.look[1] }, true); p.look = null; }
    if (p.pan) { send({ type: "pan", dx: p.pan[0], dy: p.pan[1] }, true); p.pan = null; }
    if (p.zoom) { send({ type: "zoom", factor: Math.max(0.001, Math.min(1000, p.zoom.factor)), x: p.zoom.x, y: p.zoom.y }, true); p.zoom = null; }
    if (S.keys.size) {
      const k = (c) => (S.keys.has(c) ? 1 : 0);
      const step = flySpeed() * dt;
      const f = (k("w") - k("s")) * step, r = (k("d") - k("a")) * step, u = (k("e") - k("q")) * step;
      if (f || r || u) send({ type: "move", forward: f, right: r, up: u }, true);
    }
    requestAnimationFrame(tick);
  }
  requestAnimationFrame(tick);

  // ---------------------------------------------------------------- resize
  let resizeTimer = null;
  function sendResize(now) {
    clearTimeout(resizeTimer);
    resizeTimer = setTimeout(() => { const [w, h] = deviceSize(); send({ type: "resize", width: w, height: h }, true); }, now ? 0 : 100);
  }
  new ResizeObserver(() => sendResize(false)).observe(canvas);

  // ---------------------------------------------------------------- toolbar
  $("btn-reset").addEventListener("click", () => send({ type: "reset" }, true));
  for (const b of document.querySelectorAll("[data-view]")) b.addEventListener("click", () => send({ type: "view", name: b.dataset.view }, true));
  function setFov(v, tell) {
    $("fov").value = v; $("fov-value").textContent = `${Math.round(v)}°`;
    if (tell) send({ type: "fov", value: Number(v) }, true);
  }
  $("fov").addEventListener("input", (e) => setFov(e.target.value, true));
  $("fly").addEventListener("change", (e) => setFly(e.target.checked));
  $("btn-measure").addEventListener("click", () => setMeasuring(!S.measuring));
  $("btn-section").addEventListener("click", () => setSectioning(!S.sectioning));
  $("btn-measure-close").addEventListener("click", closePolygon);
  $("btn-volume").addEventListener("click", requestVolume);
  $("btn-volume-copy").addEventListener("click", copyVolume);
  $("volume-base").addEventListener("change", (e) => $("volume-elevation-row").classList.toggle("hidden", e.target.value !== "elevation"));
  $("section-width").addEventListener("change", (e) => {
    const w = Number(e.target.value);
    const ok = e.target.value !== "" && Number.isFinite(w) && w > 0;
    e.target.classList.toggle("invalid", !ok);  // (nothing sent: the server keeps the last width)
    if (ok) send({ type: "section", action: "set", width: w }, true);
  });
  $("btn-section-enlarge").addEventListener("click", () => enlargeSection(true));
  $("section-image").addEventListener("click", () => enlargeSection(true));
  $("btn-section-close").addEventListener("click", () => enlargeSection(false));
  $("btn-section-csv").addEventListener("click", () => {
    const a = document.createElement("a");
    a.href = withToken("section.csv", { session: S.session || "" }).toString();
    a.download = "section.csv";
    document.body.append(a);
    a.click();
    a.remove();
  });
  $("speed").addEventListener("input", (e) => { S.speedExp = Number(e.target.value); updateSpeedLabel(); });
  const sendQuality = () => {
    // an emptied field was Number("") = 0: quality 10 while it showed nothing; the field shows the quality used
    const q = $("jpeg").value === "" ? NaN : Math.round(Number($("jpeg").value));
    const jpeg = Number.isFinite(q) ? Math.max(10, Math.min(100, q)) : 85;
    $("jpeg").value = jpeg;
    send({ type: "quality", adaptive: $("adaptive").checked, jpeg_quality: jpeg }, true);
  };
  $("adaptive").addEventListener("change", sendQuality);
  $("jpeg").addEventListener("change", sendQuality);
  $("btn-shot").addEventListener("click", () => {
    const a = document.createElement("a");
    a.href = withToken("screenshot", { session: S.session || "", scale: $("shot-scale").value }).toString();
    a.download = "";
    document.body.append(a);
    a.click();
    a.remove();
  });

  $("settings").addEventListener("submit", (e) => e.preventDefault());
  connect();
})();
