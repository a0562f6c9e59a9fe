// imustation monitor page: polls the JSON endpoints and draws with uPlot (vendored, no CDN).
// Read-only: only GET requests. Units: s, Hz, degC, rad/s; fitted values also in deg/h units.
"use strict";

(function () {
  const token = new URLSearchParams(window.location.search).get("token");
  // every curve its own colour: measured axes, their model overlays, and the temperatures (another palette)
  const AXIS_COLOURS = { x: "#d62728", y: "#2ca02c", z: "#1f77b4" };
  const MODEL_COLOURS = { x: "#9467bd", y: "#ff7f0e", z: "#17becf" };
  const TEMP_COLOURS = ["#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#393b79", "#637939", "#843c39", "#7b4173"];
  // units of the overlay's fitted values when the server does not send them (a gyro, SI and display)
  const GYRO_UNITS = {
    sigma_w: { si: "rad/s/\u221aHz", display: "\u00b0/h/\u221aHz", factor: 180 / Math.PI * 3600 },
    sigma_b: { si: "rad/s\u00b2/\u221aHz", display: "\u00b0/h/\u221ah", factor: 180 / Math.PI * 3600 * 60 },
    tau_b: { si: "s", display: "s", factor: 1 },
  };
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

  function withUnit(v, u) {
    // "1.75e-4 rad/s/\u221aHz (36.1 \u00b0/h/\u221aHz)": a fitted value in SI and in its display unit
    if (v === null || v === undefined) return "-";
    const si = v.toExponential(2) + " " + u.si;
    return u.display === u.si ? si : si + " (" + Number((v * u.factor).toPrecision(3)) + " " + u.display + ")";
  }

  // error bars: the 68 % interval of each measured point, drawn over the plot area (uPlot draw hook)
  function errorBars(bars) {
    return function (u) {
      const ctx = u.ctx;
      ctx.save();
      ctx.beginPath();
      ctx.rect(u.bbox.left, u.bbox.top, u.bbox.width, u.bbox.height);
      ctx.clip();
      let drawn = 0;
      bars.forEach(function (b) {
        if (!u.series[b.idx].show) return;
        ctx.strokeStyle = b.colour;
        ctx.lineWidth = 1;
        ctx.beginPath();
        for (let i = 0; i < u.data[0].length; i++) {
          const lo = b.lo[i], hi = b.hi[i], t = u.data[0][i];
          if (lo === null || hi === null || t === null || lo <= 0) continue;
          drawn++;
          const x = Math.round(u.valToPos(t, "x", true));
          const y0 = u.valToPos(lo, "y", true), y1 = u.valToPos(hi, "y", true);
          ctx.moveTo(x, y0); ctx.lineTo(x, y1);
          ctx.moveTo(x - 3, y0); ctx.lineTo(x + 3, y0);
          ctx.moveTo(x - 3, y1); ctx.lineTo(x + 3, y1);
        }
        ctx.stroke();
      });
      ctx.restore();
      u.root.setAttribute("data-error-bars", String(drawn));  // how many were drawn (the browser test reads it)
    };
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
      if (!d.tau || !d.tau.length || !axes.length) {
        // data too short for one Allan point yet: said so, not an empty section
        notes.push(name + ": waiting for data (" + (d.samples || 0) + " samples so far)\u2026");
        return;
      }
      const data = [d.tau];
      const series = [{ label: "\u03c4 (s)" }];
      const unit = d.units || "rad/s";
      const bars = [];
      axes.forEach(function (a) {
        data.push(d.axes[a].adev);
        bars.push({ idx: series.length, lo: d.axes[a].lo || [], hi: d.axes[a].hi || [],
          colour: AXIS_COLOURS[a] || "#444" });
        series.push({ label: a + " (68 % bars)", stroke: AXIS_COLOURS[a] || "#444", width: 1.5,
          points: { show: true, size: 5 },
          value: function (u, v) { return v === null ? "-" : v.toExponential(3) + " " + unit; } });
      });
      const model = d.model;
      if (model && model.axes) {
        axes.forEach(function (a) {
          const m = model.axes[a];
          if (!m || !m.adev) return;
          data.push(m.adev);
          series.push({ label: a + " model", stroke: MODEL_COLOURS[a] || "#999", width: 1.5, dash: [6, 4],
            points: { show: false },
            value: function (u, v) { return v === null ? "-" : v.toExponential(3) + " " + unit; } });
        });
      }
      let text = name + ": " + fmtDuration(d.duration_s) + " of data (" + d.samples + " samples" +
        (d.decimation > 1 ? ", shortest \u03c4 " + d.decimation + " samples" : "") + ")";
      if (model) {
        const units = model.units || GYRO_UNITS;
        const parts = axes.filter(function (a) { return model.axes[a] && !model.axes[a].error; }).map(function (a) {
          const m = model.axes[a];
          const bound = m.at_bound || [];
          // a value at its search bound is no estimate: said so, the number in brackets
          const show = function (key, text) { return bound.indexOf(key) >= 0 ? "at bound (" + text + ")" : text; };
          return a + ": \u03c3w " + withUnit(m.sigma_w, units.sigma_w) + ", \u03c3b " +
            show("sigma_b", withUnit(m.sigma_b, units.sigma_b)) + ", \u03c4b " +
            show("tau_b", m.tau_b === null ? "\u221e" : m.tau_b.toFixed(0) + " s");
        });
        text += "; ML_i " + model.model + " fitted " + (model.fitted_utc || "") + " \u2014 " + parts.join("; ");
      } else {
        text += "; model overlay after " + fmtDuration(doc.model_after_s) + " of data";
      }
      notes.push(text);
      const key = series.map(function (s) { return s.label; }).join("|");
      let chart = charts.allan[name];
      if (chart && chart._key === key) {
        chart._bars.list = bars;
        chart.setData(data);
        return;
      }
      let holder = document.getElementById("allan-" + name);
      if (!holder) {
        holder = el("div", null, "allan");
        holder.id = "allan-" + name;
        holder.appendChild(el("h3", name + ": gyro overlapping Allan deviation (" + unit + "), 68 % error bars"));
        box.appendChild(holder);
      }
      if (chart) chart.destroy();
      const barState = { list: bars };
      chart = new uPlot({
        width: plotWidth(box, names.length > 1 ? 0.49 : 1.0), height: 360, series: series,
        scales: { x: { time: false, distr: 3 }, y: { distr: 3 } },
        axes: [{ label: "\u03c4 (s)", values: logTicks }, { label: unit, values: logTicks, size: 60 }],
        hooks: { draw: [function (u) { errorBars(barState.list)(u); }] },
      }, data, holder);
      chart._key = key;
      chart._bars = barState;
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
