// imustation monitor page: polls the JSON endpoints and draws with uPlot (vendored, no CDN).
// Read-only: only GET requests. Units: s, Hz, degC, rad/s.
"use strict";

(function () {
  const token = new URLSearchParams(window.location.search).get("token");
  const AXIS_COLOURS = { x: "#d62728", y: "#2ca02c", z: "#1f77b4" };
  const TEMP_COLOURS = ["#d62728", "#1f77b4", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf"];
  const charts = { temp: null, allan: {} };

  function api(path) {
    const url = token ? path + (path.includes("?") ? "&" : "?") + "token=" + encodeURIComponent(token) : path;
    return fetch(url, { cache: "no-store", credentials: "same-origin" }).then(function (r) {
      if (!r.ok) throw new Error(path + ": HTTP " + r.status);
      return r.json();
    });
  }

  function el(tag, text, cls) {
    const e = document.createElement(tag);
    if (text !== undefined && text !== null) e.textContent = String(text);
    if (cls) e.className = cls;
    return e;
  }

  function fmtDuration(s) {
    if (s === null || s === undefined) return "-";
    s = Math.max(0, Math.round(s));
    const h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60), sec = s % 60;
    return (h ? h + "h" : "") + (h || m ? String(m).padStart(h ? 2 : 1, "0") + "m" : "") +
      String(sec).padStart(h || m ? 2 : 1, "0") + "s";
  }

  function fmtBytes(n) {
    if (n === null || n === undefined) return "-";
    const units = ["B", "KiB", "MiB", "GiB", "TiB"];
    let i = 0;
    while (n >= 1024 && i < units.length - 1) { n /= 1024; i++; }
    return (i ? n.toFixed(1) : n) + " " + units[i];
  }

  function fmtNum(v, digits) {
    return v === null || v === undefined ? "-" : Number(v).toFixed(digits);
  }

  function showError(msg) {
    const e = document.getElementById("error");
    e.hidden = !msg;
    e.textContent = msg || "";
  }

  function fillRows(tbody, rows) {
    tbody.replaceChildren();
    rows.forEach(function (cells) {
      const tr = document.createElement("tr");
      cells.forEach(function (c) { tr.appendChild(c instanceof Node ? c : el("td", c)); });
      tbody.appendChild(tr);
    });
  }

  // -- status ----------------------------------------------------------------
  function renderStatus(s) {
    document.getElementById("file").textContent = s.file + (s.part ? " (part " + s.part + ")" : "");
    const wall = s.wall_elapsed_s !== null && !s.simulated ? ", wall " + fmtDuration(s.wall_elapsed_s) : "";
    let state = s.state;
    if (s.stopped) state += " (" + s.stopped + ")";
    document.getElementById("summary").textContent =
      state + " | station " + s.station + (s.simulated ? " (simulated)" : "") + " | elapsed " +
      fmtDuration(s.elapsed_s) + wall + " | " + fmtBytes(s.file_bytes) + " | started " + s.started_utc +
      " | updated " + s.updated_utc;
    showError(s.monitor_error || "");
    const rows = Object.keys(s.devices).map(function (name) {
      const d = s.devices[name];
      const cls = d.state === "ok" || d.state === "done" ? "ok" : "bad";
      const stateCell = el("td", d.state === "stalled" ? "stalled " + fmtDuration(d.stalled_s) : d.state, cls);
      const rate = fmtNum(d.rate_recent_hz, 1) + " / " + fmtNum(d.rate_hz, 1) + " / " + d.rate_cfg_hz;
      const gaps = el("td", d.gaps, d.gaps ? "warn" : "");
      return [name, stateCell, d.samples, rate, gaps, d.lost, d.faults, d.events, fmtNum(d.temp_c, 2)];
    });
    fillRows(document.querySelector("#devices tbody"), rows);
    const trows = Object.keys(s.thermometers).map(function (name) {
      const t = s.thermometers[name];
      return [name, t.readings, fmtNum(t.celsius, 3)];
    });
    document.getElementById("thermometers").hidden = trows.length === 0;
    fillRows(document.querySelector("#thermometers tbody"), trows);
    const events = s.events.slice(-30).reverse().map(function (e) {
      return [fmtDuration(e.t_s), e.source, e.kind, e.lost, e.detail];
    });
    document.getElementById("event-count").textContent = "(last " + events.length + " of the newest " +
      s.events.length + ")";
    fillRows(document.querySelector("#events tbody"), events);
  }

  // -- plots -----------------------------------------------------------------
  function plotWidth(container, fraction) {
    const w = container.clientWidth || document.body.clientWidth || 900;
    return Math.max(320, Math.floor(w * fraction) - 10);
  }

  function logTicks(u, vals) {
    return vals.map(function (v) { return v === null ? "" : Number(v).toExponential(0); });
  }

  function renderTemps(doc) {
    const names = Object.keys(doc.series).filter(function (n) { return doc.series[n].t_s.length > 0; });
    const note = document.getElementById("warmup");
    note.replaceChildren();
    names.forEach(function (name) {
      const w = doc.warmup[name] || {};
      let text = name + ": ";
      let cls = "";
      if (w.warming === null || w.warming === undefined) {
        text += "warm-up not judged yet (needs " + fmtDuration(doc.window_s) + " of readings)";
      } else if (w.warming) {
        text += "still warming up"; cls = "warn";
      } else {
        text += "warm-up ended at " + fmtDuration(w.warmup_end_s); cls = "ok";
      }
      if (w.slope_c_per_h !== null && w.slope_c_per_h !== undefined) {
        text += "; last " + fmtDuration(doc.window_s) + ": " + w.slope_c_per_h.toFixed(3) + " \u00b0C/h (" +
          (w.steady ? "steady" : "changing") + ", limit " + doc.limit_c_per_h + " \u00b0C/h)";
      }
      note.appendChild(el("div", text, cls));
    });
    const box = document.getElementById("temp-plot");
    if (!names.length) return;
    const tables = names.map(function (n) {
      const s = doc.series[n];
      return [s.t_s.map(function (t) { return t / 3600; }), s.celsius];
    });
    const data = uPlot.join(tables);
    const key = names.join("|");
    if (charts.temp && charts.temp._key === key) {
      charts.temp.setData(data);
      return;
    }
    if (charts.temp) charts.temp.destroy();
    const series = [{ label: "t (h)" }].concat(names.map(function (n, i) {
      return {
        label: n + " (" + doc.series[n].kind + ")", stroke: TEMP_COLOURS[i % TEMP_COLOURS.length], width: 1.5,
        spanGaps: true, value: function (u, v) { return v === null ? "-" : v.toFixed(3) + " \u00b0C"; },
      };
    }));
    charts.temp = new uPlot({
      width: plotWidth(box, 1.0), height: 280, series: series,
      scales: { x: { time: false } },
      axes: [{ label: "time since start (h)" }, { label: "\u00b0C", size: 60 }],
    }, data, box);
    charts.temp._key = key;
  }

  function renderAllan(doc) {
    const box = document.getElementById("allan-plots");
    const note = document.getElementById("allan-note");
    const names = Object.keys(doc.devices);
    note.textContent = names.length ? "" : "waiting for gyro data\u2026";
    const notes = [];
    names.forEach(function (name) {
      const d = doc.devices[name];
      if (d.error) { notes.push(name + ": " + d.error); return; }
      const axes = Object.keys(d.axes || {});
      if (!d.tau || !d.tau.length || !axes.length) return;
      const data = [d.tau];
      const series = [{ label: "\u03c4 (s)" }];
      axes.forEach(function (a) {
        data.push(d.axes[a].adev);
        series.push({ label: a, stroke: AXIS_COLOURS[a] || "#444", width: 1.5,
          value: function (u, v) { return v === null ? "-" : v.toExponential(3); } });
      });
      const model = d.model;
      if (model && model.axes) {
        axes.forEach(function (a) {
          const m = model.axes[a];
          if (!m || !m.adev) return;
          data.push(m.adev);
          series.push({ label: a + " model", stroke: AXIS_COLOURS[a] || "#444", width: 1, dash: [6, 4],
            value: function (u, v) { return v === null ? "-" : v.toExponential(3); } });
        });
      }
      let text = name + ": " + fmtDuration(d.duration_s) + " of data (" + d.samples + " samples" +
        (d.decimation > 1 ? ", shortest \u03c4 " + d.decimation + " samples" : "") + ")";
      if (model) {
        const parts = axes.filter(function (a) { return model.axes[a] && !model.axes[a].error; }).map(function (a) {
          const m = model.axes[a];
          return a + ": \u03c3w " + m.sigma_w.toExponential(2) + ", \u03c3b " + m.sigma_b.toExponential(2) +
            ", \u03c4b " + (m.tau_b === null ? "\u221e" : m.tau_b.toFixed(0) + " s");
        });
        text += "; ML_i " + model.model + " fitted " + (model.fitted_utc || "") + " \u2014 " + parts.join("; ");
      } else {
        text += "; model overlay after " + fmtDuration(doc.model_after_s) + " of data";
      }
      notes.push(text);
      const key = series.map(function (s) { return s.label; }).join("|");
      let chart = charts.allan[name];
      if (chart && chart._key === key) {
        chart.setData(data);
        return;
      }
      let holder = document.getElementById("allan-" + name);
      if (!holder) {
        holder = el("div", null, "allan");
        holder.id = "allan-" + name;
        holder.appendChild(el("h3", name + ": gyro overlapping Allan deviation (rad/s)"));
        box.appendChild(holder);
      }
      if (chart) chart.destroy();
      chart = new uPlot({
        width: plotWidth(box, names.length > 1 ? 0.49 : 1.0), height: 360, series: series,
        scales: { x: { time: false, distr: 3 }, y: { distr: 3 } },
        axes: [{ label: "\u03c4 (s)", values: logTicks }, { label: "rad/s", values: logTicks, size: 60 }],
      }, data, holder);
      chart._key = key;
      charts.allan[name] = chart;
    });
    note.replaceChildren();
    notes.forEach(function (t) { note.appendChild(el("div", t)); });
  }

  // -- refresh loops ---------------------------------------------------------
  function every(ms, fn) {
    function tick() {
      fn().catch(function (e) { showError(String(e)); }).finally(function () { setTimeout(tick, ms); });
    }
    tick();
  }

  every(2000, function () { return api("api/status").then(renderStatus); });
  every(10000, function () { return api("api/temperatures?max_points=1500").then(renderTemps); });
  every(10000, function () { return api("api/allan").then(renderAllan); });
})();
