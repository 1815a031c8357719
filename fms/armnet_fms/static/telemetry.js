// The cell page's cameras and servo plots: polls /api/cells/<cell>/telemetry (latest frames'
// ages, each motor's last ~30 s) and refreshes each camera's <img> a few times a second.
// Plain SVG, names set with textContent only (they come from the agents' messages).
"use strict";
(function () {
  if (document.body.dataset.view !== "cell") return;
  // A server without a telemetry feed (armnet run --fms) says so: no section, no polling.
  if ((document.querySelector('meta[name="telemetry"]') || {}).content !== "on") return;
  document.getElementById("telemetry").hidden = false;
  const cellName = (document.querySelector('meta[name="cell"]') || {}).content || "";
  const base = `/api/cells/${encodeURIComponent(cellName)}`;
  const SVG = "http://www.w3.org/2000/svg";
  const WIDTH = 300, HEIGHT = 110, WINDOW_S = 30, POLL_MS = 400;
  const COLORS = ["#1450a3", "#b00020", "#1b7f3b", "#a06000", "#6a1b9a", "#00838f", "#5d4037", "#37474f"];
  const FIELDS = [["position", "Position (ticks)", 1], ["load", "Load (0.1 % torque)", 2], ["temperature", "Temperature (°C)", 3]];
  const cameras = document.getElementById("cameras");
  const plots = document.getElementById("plots");
  const state = document.getElementById("telemetry-state");
  const images = new Map();

  function svg(tag, attrs) {
    const node = document.createElementNS(SVG, tag);
    for (const [k, v] of Object.entries(attrs || {})) node.setAttribute(k, String(v));
    return node;
  }

  function cameraImage(name) {
    let img = images.get(name);
    if (img) return img;
    const figure = document.createElement("figure");
    img = document.createElement("img");
    img.className = "camera";
    img.id = `camera-${name}`;
    img.alt = `camera ${name}`;
    img.dataset.loading = "";
    img.addEventListener("load", () => { img.dataset.loading = ""; });
    img.addEventListener("error", () => { img.dataset.loading = ""; });
    const caption = document.createElement("figcaption");
    caption.textContent = name;
    figure.append(img, caption);
    cameras.appendChild(figure);
    images.set(name, img);
    return img;
  }

  function renderCameras(list) {
    for (const cam of list) {
      const img = cameraImage(cam.name);
      if (img.dataset.loading) continue; // the previous frame is still on its way: never pile up requests
      img.dataset.loading = "1";
      img.src = `${base}/camera/${encodeURIComponent(cam.name)}.jpg?t=${Date.now()}`;
    }
  }

  // A quantity the latest reading does not read (the server's ``unread``: load and temperature
  // while a job runs) gets no line at all, not even from reads before: the text says it is not read.
  function plot(field, title, index, series, notRead) {  // notRead: why, or ""
    const figure = document.createElement("figure");
    figure.className = "plot";
    const chart = svg("svg", { viewBox: `0 0 ${WIDTH} ${HEIGHT}`, role: "img", "aria-label": title, class: "plot" });
    chart.dataset.field = field;
    const drawnSeries = notRead ? [] : series;
    let lo = Infinity, hi = -Infinity;
    for (const s of drawnSeries) for (const p of s.points) {
      if (p[index] === null) continue;
      lo = Math.min(lo, p[index]); hi = Math.max(hi, p[index]);
    }
    const known = hi >= lo;
    if (!known) { lo = 0; hi = 1; }
    if (hi - lo < 1) { lo -= 1; hi += 1; }
    chart.appendChild(svg("rect", { x: 0, y: 0, width: WIDTH, height: HEIGHT, class: "plot-bg" }));
    let drawn = 0;
    drawnSeries.forEach((s, i) => {
      const valued = s.points.filter((p) => p[index] !== null);
      if (!valued.length) return;
      const points = valued.map((p) => {
        const x = WIDTH * (1 - Math.min(p[0], WINDOW_S) / WINDOW_S);
        const y = HEIGHT - 4 - (HEIGHT - 8) * (p[index] - lo) / (hi - lo);
        return `${x.toFixed(1)},${y.toFixed(1)}`;
      });
      const line = svg("polyline", { points: points.join(" "), fill: "none", stroke: COLORS[i % COLORS.length], "stroke-width": 1.5 });
      line.dataset.motor = `${s.arm}/${s.motor}`;
      chart.appendChild(line);
      drawn += valued.length;
    });
    chart.dataset.points = String(drawn);
    const caption = document.createElement("figcaption");
    caption.textContent = notRead ? `${title}: ${notRead}` : known ? `${title}: ${Math.round(lo)} … ${Math.round(hi)}`
      : `${title}: no readings`;
    figure.append(chart, caption);
    return figure;
  }

  function legend(series) {
    const box = document.createElement("p");
    box.className = "legend";
    series.forEach((s, i) => {
      const item = document.createElement("span");
      item.className = `swatch c${i % COLORS.length}`;
      item.textContent = `${s.arm}/${s.motor}`;
      box.appendChild(item);
    });
    return box;
  }

  function render(t) {
    renderCameras(t.cameras || []);
    const series = t.series || [];
    const unread = t.unread || [];
    const why = t.source === "job" ? "not read while a job runs" : "not read";
    plots.replaceChildren(...FIELDS.map(([field, title, index]) =>
      plot(field, title, index, series, unread.includes(field) ? why : "")), legend(series));
    const parts = [];
    if (t.ageS === null || t.ageS === undefined) parts.push("no servo readings yet");
    else {
      const who = t.source === "job" ? "positions from the job's own reads" : "cell idle";
      const missing = unread.length ? `; ${unread.join(" and ")} ${unread.length > 1 ? "are" : "is"} ${why}` : "";
      parts.push(`servos read ${t.ageS < 2 ? "just now" : Math.round(t.ageS) + " s ago"} (${who}${missing})`);
    }
    // The arm's name in quotes, first: an arm is often named "arm" (never "arm arm: …").
    for (const e of t.errors || []) parts.push(`“${e.arm}” not plotted: ${e.error}`);
    // The completion monitor's verdict now, while a job runs on a cell with one (docs/fms.md).
    const m = t.monitor;
    if (m) parts.push(`completion monitor: ${m.complete ? "complete" : "not complete"} (score ${m.score.toFixed(2)})`);
    state.textContent = parts.join("; ");
  }

  let delay = POLL_MS;
  async function poll() {
    try {
      const response = await fetch(`${base}/telemetry`, { credentials: "same-origin", cache: "no-store" });
      if (response.ok) render(await response.json());
      delay = POLL_MS;
    } catch (e) {
      state.textContent = "telemetry unavailable";
      delay = Math.min(delay * 2, 5000); // the FMS is away: ask less often until it answers
    }
    setTimeout(poll, delay);
  }
  poll();
})();
