// The station panel's page: the form, the live view of a run (server-sent events), the verdict.
// Every value from the run or the operator is put on the page as text (textContent), never as
// markup. No library: the plot is drawn on a canvas here.
"use strict";

(function () {
  const data = JSON.parse(document.getElementById("panel-data").textContent);
  const T = data.texts;
  const $ = (id) => document.getElementById(id);
  const PLOT_WINDOW_S = 60;
  const COLOURS = { stand: "#1565c0", instrument: "#e65100" };

  let run = null; // the run as the server last described it
  let trace = []; // plot points {t, stand: {axis: deg}, instrument: {axis: deg}}
  let shownView = "";

  // ---- small helpers
  function text(el, value) {
    const v = value == null ? "" : String(value);
    if (el.textContent !== v) el.textContent = v; // unchanged: not announced again
  }
  function mmss(s) {
    if (s == null || !isFinite(s)) return "--:--";
    s = Math.max(0, s);
    const m = Math.floor(s / 60), r = Math.floor(s % 60);
    return String(m).padStart(2, "0") + ":" + String(r).padStart(2, "0");
  }
  // numbers the station's language's way (a decimal comma in Russian)
  const LANG = document.documentElement.lang || "en";
  function num(v, digits) {
    if (v == null || !isFinite(v)) return "—";
    return Number(v).toLocaleString(LANG, { minimumFractionDigits: digits,
      maximumFractionDigits: digits, useGrouping: false });
  }
  function plain(v) {
    return v == null || !isFinite(v) ? "—" : Number(v).toLocaleString(LANG, { useGrouping: false });
  }
  function el(tag, content, cls) {
    const e = document.createElement(tag);
    if (content != null) e.textContent = String(content);
    if (cls) e.className = cls;
    return e;
  }
  function clear(node) { while (node.firstChild) node.removeChild(node.firstChild); }

  async function post(url, body) {
    const resp = await fetch(url, {
      method: "POST", credentials: "same-origin",
      headers: { "Content-Type": "application/json", "X-CSRF-Token": data.csrf },
      body: JSON.stringify(body || {}),
    });
    let payload = {};
    try { payload = await resp.json(); } catch (e) { payload = {}; }
    return { ok: resp.ok, status: resp.status, payload: payload };
  }

  // ---- views
  function show(view) {
    for (const id of ["setup", "live", "verdict"]) $(id).hidden = id !== view;
    if (view === shownView) return;
    shownView = view;
    if (view === "setup") {
      const serial = $("serial");
      serial.value = "";
      text($("serial-status"), "");
      formError("", "");
      $("start").disabled = false;
      serial.focus();
    } else if (view === "live") {
      $("stop").disabled = false;
      $("stop").focus();
    } else if (view === "verdict") {
      $("new-test").focus();
    }
  }

  function render(status) {
    run = status.run;
    if (!$("operator").value && status.last_operator) $("operator").value = status.last_operator;
    if (!run) { trace = []; show("setup"); return; }
    trace = (run.trace || []).slice();
    if (run.ended) { hidePrompt(); renderVerdict(run); show("verdict"); return; }
    text($("live-serial"), run.serial);
    text($("live-operator"), run.operator);
    text($("live-profile"), run.profile);
    clear($("messages"));
    for (const m of run.messages || []) addMessage(m);
    setState(run.state, run.reason_text, run.reason_detail);
    if (run.snapshot) renderSnapshot(run.snapshot);
    $("stopping").hidden = !run.stop_requested;
    if (run.stop_requested) { text($("stopping"), T.stopping); $("stop").disabled = true; }
    show("live");
    if (run.prompt) showPrompt(run.prompt); else hidePrompt();
    drawPlot();
  }

  // ---- a plan's question: a modal dialog, answered Yes or No (No is focused: Enter is no)
  let promptId = null;
  function showPrompt(p) {
    const dialog = $("prompt");
    promptId = p.id;
    text($("prompt-text"), p.text);
    text($("prompt-timeout"), p.timeout_s ? T.prompt_timeout.replace("%(s)s", p.timeout_s) : "");
    $("prompt-yes").disabled = false;
    $("prompt-no").disabled = false;
    if (!dialog.open) dialog.showModal();
    $("prompt-no").focus();
  }
  function hidePrompt(id) {
    if (id != null && id !== promptId) return;
    promptId = null;
    const dialog = $("prompt");
    if (dialog.open) dialog.close();
    if (!$("live").hidden && !$("stop").disabled) $("stop").focus();
  }
  async function answer(yes) {
    const id = promptId;
    if (id == null) return;
    $("prompt-yes").disabled = true;
    $("prompt-no").disabled = true;
    const r = await post("/api/answer", { id: id, yes: yes });
    if (r.ok) { hidePrompt(id); return; } // the next question may be up already: not that one
    if (promptId === id) { $("prompt-yes").disabled = false; $("prompt-no").disabled = false; }
  }

  function setState(state, reason, detail) {
    text($("state"), (T[state] || state) + (reason ? " (" + reason + ")" : ""));
    text($("state-detail"), detail || "");
  }

  function axisName(a) { return T["axis_" + a] || a; }

  // a message of the run: the panel's words for it, and the run's own (English) as a detail
  function addMessage(m) {
    const list = $("messages");
    const li = document.createElement("li");
    if (m.text) li.appendChild(el("span", m.text));
    if (m.detail) li.appendChild(el("span", m.detail, "detail"));
    list.appendChild(li);
    while (list.children.length > 50) list.removeChild(list.firstChild);
  }

  function formError(message, detail) {
    text($("form-error"), message);
    text($("form-detail"), detail);
  }

  function judgement(snap) {
    if (snap.limit_deg == null || snap.sigma_judged_after_s == null) return "";
    if (snap.elapsed_s == null || snap.elapsed_s < snap.sigma_judged_after_s) return "settling";
    const values = Object.values(snap.sigma_deg || {}).filter((v) => v != null && isFinite(v));
    if (!values.length) return "settling";
    return Math.max.apply(null, values) > snap.limit_deg ? "over" : "within";
  }

  function renderSnapshot(snap) {
    text($("elapsed"), mmss(snap.elapsed_s));
    text($("remaining"), mmss(snap.remaining_s));
    const body = $("angles");
    clear(body);
    const axes = Object.keys(snap.stand_deg || {});
    for (const a of Object.keys(snap.instrument_deg || {})) if (!axes.includes(a)) axes.push(a);
    for (const a of axes) {
      const tr = document.createElement("tr");
      tr.appendChild(el("td", axisName(a)));
      tr.appendChild(el("td", num((snap.stand_deg || {})[a], 2)));
      tr.appendChild(el("td", num((snap.instrument_deg || {})[a], 2)));
      tr.appendChild(el("td", num((snap.tracking_error_deg || {})[a], 3)));
      tr.appendChild(el("td", num((snap.sigma_deg || {})[a], 3)));
      body.appendChild(tr);
    }
    const sig = Object.entries(snap.sigma_deg || {})
      .map(([a, v]) => axisName(a) + " " + num(v, 3) + "°").join("  ");
    const limit = snap.limit_deg == null ? "" : "   " + T.limit + " " + plain(snap.limit_deg) + "°";
    text($("sigma"), (sig || "—") + limit);
    const j = judgement(snap);
    const judged = $("sigma-judged");
    judged.className = j === "over" ? "judged-over" : j === "within" ? "judged-within" : "";
    if (j === "settling" && snap.sigma_judged_after_s != null) {
      text(judged, "(" + T.settling + ", " + mmss(snap.sigma_judged_after_s - (snap.elapsed_s || 0)) + ")");
    } else {
      text(judged, j ? "(" + T[j] + ")" : snap.limit_deg != null ? "(" + T.not_judged + ")" : "");
    }
    const buffered = snap.mode === "buffered" || snap.mode === "table";
    const touched = (!buffered && snap.cycles && snap.missed_cycles / snap.cycles > 0.01)
      || snap.underruns > 0 || snap.rejoins > 0;
    const parts = [(buffered ? T.missed_polls : T.missed_cycles) + " " + snap.missed_cycles,
      T.rejoins + " " + snap.rejoins, T.samples + " " + snap.instrument_samples];
    if (snap.underruns) parts.splice(1, 0, T.underruns + " " + snap.underruns);
    const health = $("health");
    text(health, (touched ? T.health_warn : T.health_ok) + " — " + parts.join(", "));
    health.className = touched ? "warning" : "";
  }

  function renderVerdict(r) {
    const o = r.outcome || {};
    const word = $("verdict-word");
    text(word, o.word || T[o.verdict] || o.verdict);
    word.className = "verdict " + (o.verdict || "");
    text($("verdict-serial"), r.serial + " · " + r.operator + " · " + r.profile);
    const body = $("verdict-axes");
    clear(body);
    for (const a of o.axes || []) {
      const tr = document.createElement("tr");
      tr.appendChild(el("td", a.axis_name || a.axis));
      tr.appendChild(el("td", num(a.sigma, 4)));
      tr.appendChild(el("td", num(a.ci[0], 4) + " … " + num(a.ci[1], 4)));
      tr.appendChild(el("td", plain(a.limit)));
      tr.appendChild(el("td", a.word || T[a.verdict] || a.verdict));
      body.appendChild(tr);
    }
    body.parentElement.hidden = !(o.axes || []).length;
    const steps = $("verdict-steps");
    clear(steps);
    (o.steps || []).forEach((s, i) => {
      const tr = document.createElement("tr");
      tr.appendChild(el("td", s.name));
      tr.appendChild(el("td", s.word || s.verdict));
      tr.appendChild(el("td", s.detail || "", "detail"));
      const cell = document.createElement("td");
      if (s.report) {
        const a = el("a", T.open_report, "link");
        a.href = "/runs/" + Number(r.id) + "/steps/" + i + "/report";
        cell.appendChild(a);
      }
      tr.appendChild(cell);
      steps.appendChild(tr);
    });
    $("verdict-steps-table").hidden = !(o.steps || []).length;
    text($("verdict-title"), o.headline || "");
    text($("verdict-reason"), o.detail ? o.details_label + ": " + o.detail : "");
    text($("verdict-stand"), o.stand_text || "");
    text($("verdict-stand-detail"), o.stand_detail || "");
    const next = $("verdict-next");
    clear(next);
    if (o.verdict === "ABORTED") {
      if (o.measured) {
        next.appendChild(el("p", T.measured_before + " " + (o.measured_word || o.measured.verdict)));
      }
      if ((o.next || []).length) {
        next.appendChild(el("p", T.next_commands, "warning"));
        const list = document.createElement("ol");
        for (const c of o.next) { const li = document.createElement("li"); li.appendChild(el("code", c)); list.appendChild(li); }
        next.appendChild(list);
      } else if (o.at_zero) {
        next.appendChild(el("p", T.at_rest));
      }
      if (o.advice) next.appendChild(el("p", o.advice));
    }
    const link = $("report-link");
    link.hidden = !o.report;
    link.href = o.report ? "/runs/" + Number(r.id) + "/report" : "/";
  }

  // ---- the plot: stand and instrument angles over the last PLOT_WINDOW_S seconds
  function drawPlot() {
    const canvas = $("plot");
    if (!canvas || $("live").hidden) return;
    const ctx = canvas.getContext("2d");
    const W = canvas.width, H = canvas.height, L = 56, R = 10, TOP = 10, B = 28;
    ctx.clearRect(0, 0, W, H);
    if (!trace.length) return;
    const tEnd = trace[trace.length - 1].t;
    const t0 = Math.max(0, tEnd - PLOT_WINDOW_S);
    const pts = trace.filter((p) => p.t >= t0);
    let lo = Infinity, hi = -Infinity;
    for (const p of pts) for (const k of ["stand", "instrument"]) for (const v of Object.values(p[k] || {})) {
      if (v != null && isFinite(v)) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
    }
    if (!isFinite(lo)) { lo = -1; hi = 1; }
    const span = Math.max(hi - lo, 1);
    lo -= span * 0.1; hi += span * 0.1;
    const x = (t) => L + (t - t0) / PLOT_WINDOW_S * (W - L - R);
    const y = (v) => TOP + (hi - v) / (hi - lo) * (H - TOP - B);
    ctx.strokeStyle = "#ddd"; ctx.fillStyle = "#555"; ctx.lineWidth = 1;
    ctx.font = "14px system-ui, sans-serif";
    const step = niceStep((hi - lo) / 5);
    for (let v = Math.ceil(lo / step) * step; v <= hi; v += step) {
      ctx.beginPath(); ctx.moveTo(L, y(v)); ctx.lineTo(W - R, y(v)); ctx.stroke();
      ctx.fillText(v.toFixed(step < 1 ? 1 : 0) + "°", 4, y(v) + 5);
    }
    for (let t = Math.ceil(t0 / 10) * 10; t <= t0 + PLOT_WINDOW_S; t += 10) {
      ctx.fillText(mmss(t), Math.min(x(t) - 18, W - 44), H - 8);
    }
    const axes = Object.keys(pts[pts.length - 1].stand || {});
    ctx.lineWidth = 2;
    for (const k of ["stand", "instrument"]) {
      axes.forEach((a, i) => {
        ctx.strokeStyle = COLOURS[k];
        ctx.setLineDash(i ? [6, 4] : []);
        ctx.beginPath();
        let started = false;
        for (const p of pts) {
          const v = (p[k] || {})[a];
          if (v == null || !isFinite(v)) { started = false; continue; }
          if (started) ctx.lineTo(x(p.t), y(v)); else { ctx.moveTo(x(p.t), y(v)); started = true; }
        }
        ctx.stroke();
      });
    }
    ctx.setLineDash([]);
  }

  function niceStep(raw) {
    const p = Math.pow(10, Math.floor(Math.log10(raw)));
    for (const m of [1, 2, 5, 10]) if (raw <= m * p) return m * p;
    return 10 * p;
  }

  // ---- the live events
  function connect() {
    const source = new EventSource("/api/events");
    source.addEventListener("open", () => text($("conn"), ""));
    source.addEventListener("error", () => text($("conn"), T.connection_lost));
    source.addEventListener("status", (e) => render(JSON.parse(e.data)));
    source.addEventListener("snapshot", (e) => {
      if (!run || run.ended) return;
      const d = JSON.parse(e.data);
      renderSnapshot(d.snapshot);
      if (d.snapshot.state !== run.state) { run.state = d.snapshot.state; setState(run.state, "", ""); }
      if (d.point) { trace.push(d.point); if (trace.length > 3000) trace.shift(); }
    });
    source.addEventListener("state", (e) => {
      const d = JSON.parse(e.data);
      if (run && !run.ended) { run.state = d.state; setState(d.state, d.reason_text, d.reason_detail); }
    });
    source.addEventListener("message", (e) => addMessage(JSON.parse(e.data)));
    source.addEventListener("stopping", () => {
      $("stopping").hidden = false;
      text($("stopping"), T.stopping);
      $("stop").disabled = true;
    });
    source.addEventListener("prompt", (e) => {
      if (run && !run.ended) showPrompt(JSON.parse(e.data));
    });
    source.addEventListener("prompt_closed", (e) => hidePrompt(JSON.parse(e.data).id));
    source.addEventListener("ended", (e) => render({ run: JSON.parse(e.data).run }));
  }

  // ---- the form: Enter in the serial checks it (a scanner types it and Enter)
  async function checkSerial() {
    const serial = $("serial");
    formError("", "");
    const r = await post("/api/check-serial", { serial: serial.value });
    if (!r.ok) {
      text($("serial-status"), "");
      formError(r.payload.error || r.status, r.payload.detail || "");
      serial.select();
      return false;
    }
    serial.value = r.payload.serial;
    text($("serial-status"), "✓ " + T.serial_ok);
    return true;
  }

  $("serial").addEventListener("keydown", async (e) => {
    if (e.key !== "Enter") return;
    e.preventDefault();
    if (await checkSerial()) ($("operator").value ? $("start") : $("operator")).focus();
  });
  $("serial").addEventListener("input", () => text($("serial-status"), ""));
  $("start-form").addEventListener("submit", async (e) => {
    e.preventDefault();
    $("start").disabled = true;
    formError("", "");
    const r = await post("/api/start", {
      serial: $("serial").value, operator: $("operator").value, profile: $("profile").value,
    });
    if (!r.ok) {
      $("start").disabled = false;
      formError(r.payload.error || r.status, r.payload.detail || "");
      $("serial").focus();
    }
  });
  $("stop").addEventListener("click", async () => {
    $("stop").disabled = true;
    const r = await post("/api/stop");
    if (!r.ok) $("stop").disabled = false;
  });
  $("prompt-yes").addEventListener("click", () => answer(true));
  $("prompt-no").addEventListener("click", () => answer(false));
  $("prompt").addEventListener("cancel", (e) => e.preventDefault()); // Escape is no answer
  $("new-test").addEventListener("click", async () => {
    const r = await post("/api/dismiss");
    if (r.ok) render({ run: null, last_operator: $("operator").value });
  });

  setInterval(drawPlot, 200);
  connect();
})();
