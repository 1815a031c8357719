// The FMS page: follows /live (server-sent events) and renders with textContent only
// (cell, job and condition texts come from tenants' objects: never parsed as HTML).
"use strict";
(function () {
  const meta = (name) => (document.querySelector(`meta[name="${name}"]`) || {}).content || "";
  const view = document.body.dataset.view;
  const cellName = meta("cell");
  let latest = null;

  function el(tag, cls, text) {
    const node = document.createElement(tag);
    if (cls) node.className = cls;
    if (text !== undefined) node.textContent = text;
    return node;
  }

  function age(seconds) {
    if (seconds === null || seconds === undefined) return "never";
    if (seconds < 90) return `${Math.round(seconds)} s ago`;
    return `${Math.round(seconds / 60)} min ago`;
  }

  function cellCard(cell, linked, big) {
    const card = el("div", `card phase-${cell.phase}${big ? " big" : ""}`);
    card.id = `cell-${cell.name}`;
    const title = el("h2");
    if (linked) {
      const a = el("a", "", cell.name);
      a.href = `/cells/${encodeURIComponent(cell.name)}`;
      title.appendChild(a);
    } else title.textContent = cell.name;
    card.appendChild(title);
    const badges = el("p");
    badges.appendChild(el("span", "badge phase", cell.phase));
    badges.appendChild(el("span", `badge interlock ${cell.interlock}`, `interlock ${cell.interlock}`));
    if (cell.unschedulable) badges.appendChild(el("span", "badge", "cordoned"));
    if (cell.reset) badges.appendChild(el("span", "badge waiting", "reset waiting"));
    if (cell.site) badges.appendChild(el("span", "badge", `site ${cell.site}`));
    card.appendChild(badges);
    const job = cell.job;
    card.appendChild(el("p", "job", job ? `Job ${job.namespace}/${job.name} (${job.phase})` : "No job"));
    if (job && job.rolloutIndex !== null) {
      const total = job.rolloutTotal ? `/${job.rolloutTotal}` : "";
      card.appendChild(el("p", "rollout", `Rollout ${job.rolloutIndex}${total}${job.rolloutActive ? "" : " (ended)"}`));
    }
    if (job && job.progress) card.appendChild(el("p", "progress", job.progress));
    for (const c of cell.falseConditions) {
      card.appendChild(el("p", "cond", `${c.type}: ${c.reason}${c.message ? " (" + c.message + ")" : ""}`));
    }
    card.appendChild(el("p", "heartbeat", `Heartbeat ${age(cell.heartbeatAgeS)}`));
    return card;
  }

  function renderFeedState(data) {
    const state = document.getElementById("feed-state");
    const problems = [];
    if (!data.kubeOk) problems.push("Kubernetes API unreachable: the view may be stale");
    if (!data.natsOk) problems.push("NATS down: buttons cannot reach jobs");
    state.textContent = problems.length ? problems.join("; ") : `live, updated ${new Date().toLocaleTimeString()}`;
    state.className = problems.length ? "feed down" : "feed";
  }

  function renderFleet(data) {
    const box = document.getElementById("cells");
    const q = document.getElementById("filter-q").value.toLowerCase();
    const site = document.getElementById("filter-site").value;
    box.replaceChildren(...data.cells
      .filter((c) => (!q || c.name.toLowerCase().includes(q)) && (!site || c.site === site))
      .map((c) => cellCard(c, true, false)));
  }

  let resetDeadline = 0;
  function renderCell(data) {
    const cell = data.cells.find((c) => c.name === cellName);
    const card = document.getElementById("cell-card");
    if (!cell) { card.replaceChildren(el("p", "", "This cell does not exist (or is not yours to see).")); return; }
    card.replaceChildren(...cellCard(cell, false, true).childNodes);
    card.className = `card big phase-${cell.phase}`;
    const job = cell.job, active = !!(job && job.active);
    const resetBox = document.getElementById("reset-box");
    resetBox.hidden = !cell.reset;
    if (cell.reset) {
      resetBox.dataset.request = cell.reset.request;
      resetDeadline = Date.now() + cell.reset.secondsLeft * 1000;
    }
    tickReset();
    // Success/Fail only while a rollout that asked for them runs: after its end a verdict would be dropped.
    const rolling = active && job.rolloutIndex !== null && job.rolloutActive && job.outcomeControls;
    document.getElementById("outcome-box").hidden = !rolling;
    if (rolling) {
      document.getElementById("outcome-box").dataset.rollout = String(job.rolloutIndex);
      document.getElementById("outcome-rollout").textContent =
        `${job.rolloutIndex}${job.rolloutTotal ? "/" + job.rolloutTotal : ""}`;
    }
    renderVerdicts((job && job.verdicts) || []);
    document.getElementById("stop-box").hidden = !active;
    document.getElementById("cordon").hidden = cell.unschedulable;
    document.getElementById("uncordon").hidden = !cell.unschedulable;
  }

  function renderVerdicts(verdicts) {
    const list = document.getElementById("verdicts");
    document.getElementById("verdicts-box").hidden = !verdicts.length;
    list.replaceChildren(...verdicts.map((v) => el("li", `verdict ${v.outcome}`,
      `Rollout ${v.index}${v.total ? "/" + v.total : ""}: ${v.outcome}, marked by ${v.by || "?"}` +
      (v.at ? ` at ${new Date(v.at).toLocaleTimeString()}` : ""))));
  }

  function tickReset() {
    const left = Math.max(0, Math.round((resetDeadline - Date.now()) / 1000));
    const node = document.getElementById("reset-left");
    if (node) node.textContent = `${left} s left before the reset times out.`;
  }

  async function act(action, body) {
    const out = document.getElementById("action-result");
    out.className = ""; out.textContent = "sending…";
    try {
      const response = await fetch(`/api/cells/${encodeURIComponent(cellName)}/${action}`, {
        method: "POST", credentials: "same-origin",
        headers: {"Content-Type": "application/json", "X-CSRF-Token": meta("csrf")},
        body: JSON.stringify(body || {}),
      });
      const reply = await response.json();
      out.textContent = response.ok ? reply.message : reply.error;
      out.className = response.ok ? "" : "error";
    } catch (err) {
      out.textContent = "the FMS did not answer; try again"; out.className = "error";
    }
  }

  function wireCellButtons() {
    document.getElementById("confirm-reset").addEventListener("click", () => {
      const request = document.getElementById("reset-box").dataset.request || "";
      document.getElementById("reset-box").hidden = true;  // one click, one confirmation
      act("confirm-reset", {request});
    });
    const rollout = () => document.getElementById("outcome-box").dataset.rollout || "";
    document.getElementById("mark-success").addEventListener("click", () => act("success", {request: rollout()}));
    document.getElementById("mark-fail").addEventListener("click", () => act("fail", {request: rollout()}));
    const stop = document.getElementById("stop");
    let armed = 0;
    stop.addEventListener("click", () => {
      // Two taps: a tablet in a pocket must not stop a job.
      if (Date.now() - armed < 5000) { armed = 0; stop.textContent = "Stop job"; act("stop"); return; }
      armed = Date.now(); stop.textContent = "Tap again to stop";
      setTimeout(() => { if (armed && Date.now() - armed >= 5000) { armed = 0; stop.textContent = "Stop job"; } }, 5100);
    });
    document.getElementById("cordon").addEventListener("click", () => act("cordon"));
    document.getElementById("uncordon").addEventListener("click", () => act("uncordon"));
    setInterval(tickReset, 1000);
  }

  function render() {
    if (!latest) return;
    renderFeedState(latest);
    if (view === "fleet") renderFleet(latest); else renderCell(latest);
  }

  function follow() {
    const query = view === "cell" ? `?cell=${encodeURIComponent(cellName)}` : "";
    const source = new EventSource(`/live${query}`);
    source.onmessage = (event) => { latest = JSON.parse(event.data); render(); };
    source.onerror = () => {
      const state = document.getElementById("feed-state");
      state.textContent = "reconnecting to the live feed…"; state.className = "feed down";
    };
  }

  if (view === "fleet") {
    document.getElementById("filter-q").addEventListener("input", render);
    document.getElementById("filter-site").addEventListener("input", render);
  } else wireCellButtons();
  follow();
})();
