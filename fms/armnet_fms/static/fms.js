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

  function within(seconds) {
    if (seconds < 1) return "any moment";
    if (seconds < 90) return `in ${Math.round(seconds)} s`;
    return `in ${Math.round(seconds / 60)} min`;
  }

  // The operator's summary of the queue at the cell (status.queue): counts and times only.
  function queueText(queue) {
    const waiting = queue.waitingJobs === 1 ? "1 job waiting" : `${queue.waitingJobs} jobs waiting`;
    const likely = queue.likelyFreeInS ?? queue.latestFreeInS;
    if (likely === null || likely === undefined) return `${waiting}; no job holds the cell`;
    const latest = queue.latestFreeInS !== null && queue.latestFreeInS > likely
      ? `, at the latest ${within(queue.latestFreeInS)}` : "";
    return `${waiting}; its job likely ends ${within(likely)}${latest}`;
  }

  // A fleet card is one link stretched over the whole card (fms.css): a tap anywhere on it, or
  // Enter on its focused name, opens the cell. Cards are updated in place, never replaced, so a
  // tap or the keyboard focus survives the live feed's re-renders (twice a second).
  function fleetCard(cell) {
    let card = document.getElementById(`cell-${cell.name}`);
    if (!card) {
      card = el("div");
      card.id = `cell-${cell.name}`;
      const title = el("h2");
      const a = el("a", "open", cell.name);
      a.href = `/cells/${encodeURIComponent(cell.name)}`;
      title.appendChild(a);
      card.appendChild(title);
    }
    card.className = `card linked phase-${cell.phase}`;
    const title = card.firstElementChild;
    while (title.nextSibling) title.nextSibling.remove();
    card.append(...cardFacts(cell));
    return card;
  }

  function cardFacts(cell) {
    const facts = [];
    const badges = el("p");
    badges.appendChild(el("span", "badge phase", cell.phase));
    badges.appendChild(el("span", `badge interlock ${cell.interlock}`, `interlock ${cell.interlock}`));
    if (cell.unschedulable) badges.appendChild(el("span", "badge", "cordoned"));
    if (cell.preflight) badges.appendChild(el("span", "badge", "pre-flight twin"));
    if (cell.phase === "Resting" && cell.restEndsInS !== null) {
      badges.appendChild(el("span", "badge waiting", `resting, back ${within(cell.restEndsInS)}`));
    }
    if (cell.reset) badges.appendChild(el("span", "badge waiting", "reset waiting"));
    if (cell.site) badges.appendChild(el("span", "badge", `site ${cell.site}`));
    facts.push(badges);
    const job = cell.job;
    facts.push(el("p", "job", job ? `Job ${job.namespace}/${job.name} (${job.phase})` : "No job"));
    if (job && job.rolloutIndex !== null) {
      const total = job.rolloutTotal ? `/${job.rolloutTotal}` : "";
      facts.push(el("p", "rollout", `Rollout ${job.rolloutIndex}${total}${job.rolloutActive ? "" : " (ended)"}`));
    }
    if (job && job.progress) facts.push(el("p", "progress", job.progress));
    for (const c of cell.falseConditions) {
      facts.push(el("p", "cond", `${c.type}: ${c.reason}${c.message ? " (" + c.message + ")" : ""}`));
    }
    if (cell.queue) facts.push(el("p", "queue", queueText(cell.queue)));
    facts.push(el("p", "heartbeat", `Heartbeat ${age(cell.heartbeatAgeS)}`));
    return facts;
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
    const cards = data.cells
      .filter((c) => (!q || c.name.toLowerCase().includes(q)) && (!site || c.site === site))
      .map(fleetCard);
    // Only a card out of place is moved: moving one drops a tap in progress and the focus.
    cards.forEach((card, i) => { if (box.children[i] !== card) box.insertBefore(card, box.children[i] || null); });
    while (box.children.length > cards.length) box.lastElementChild.remove();
  }

  // Nothing moves under a finger: each control has its own slot, kept (invisible, untappable)
  // while the control does not apply, so Confirm reset and Success/Fail never share a spot.
  function show(node, shown) { node.classList.toggle("off", !shown); }

  // A button that appears, or comes to act on something else (another reset, rollout, job),
  // ignores taps for ARM_MS, drawn greyed with a filling bar: a late second tap on the spot
  // never confirms a reset nobody did nor judges a rollout nobody watched (docs/fms.md).
  const ARM_MS = 1500;
  const armTimers = new Map();
  function offer(buttons, key) {  // key: what the buttons act on now, "" while they are not shown
    for (const button of buttons) {
      if (button.dataset.armedFor === key) continue;
      button.dataset.armedFor = key;
      if (key) disarm(button);
    }
  }
  function disarm(button) {
    clearTimeout(armTimers.get(button));
    button.disabled = true;
    button.classList.remove("arming");
    void button.offsetWidth;  // restarts the bar's animation
    button.style.setProperty("--arm-ms", `${ARM_MS}ms`);
    button.classList.add("arming");
    armTimers.set(button, setTimeout(() => { button.disabled = false; button.classList.remove("arming"); }, ARM_MS));
  }

  let resetDeadline = 0;
  let confirmedRequest = "";  // the reset this page confirmed: its box stays hidden while the feed catches up
  function renderCell(data) {
    const cell = data.cells.find((c) => c.name === cellName);
    const card = document.getElementById("cell-card");
    if (!cell) { card.replaceChildren(el("p", "", "This cell does not exist (or is not yours to see).")); return; }
    card.replaceChildren(el("h2", "", cell.name), ...cardFacts(cell));
    card.className = `card big phase-${cell.phase}`;
    // The FMS streams the last ended job's video from the store (it says why when there is none).
    const videoBox = document.getElementById("last-video-box");
    if (videoBox && meta("video") === "on" && videoBox.hidden) {
      document.getElementById("last-video").href = `/api/cells/${encodeURIComponent(cellName)}/last-video.mp4`;
      videoBox.hidden = false;
    }
    const job = cell.job, active = !!(job && job.active);
    const jobKey = active ? `${job.namespace}/${job.name}` : "";
    const resetBox = document.getElementById("reset-box");
    const resetShown = !!cell.reset && cell.reset.request !== confirmedRequest;
    show(resetBox, resetShown);
    if (resetShown) {
      resetBox.dataset.request = cell.reset.request;
      resetDeadline = Date.now() + cell.reset.secondsLeft * 1000;
    }
    offer([document.getElementById("confirm-reset")], resetShown ? cell.reset.request : "");
    tickReset();
    // Success/Fail only while a rollout that asked for them runs: after its end a verdict would be dropped.
    const rolling = active && job.rolloutIndex !== null && job.rolloutActive && job.outcomeControls;
    const outcomeBox = document.getElementById("outcome-box");
    show(outcomeBox, rolling);
    if (rolling) {
      outcomeBox.dataset.rollout = String(job.rolloutIndex);
      document.getElementById("outcome-rollout").textContent =
        `${job.rolloutIndex}${job.rolloutTotal ? "/" + job.rolloutTotal : ""}`;
    }
    offer([document.getElementById("mark-success"), document.getElementById("mark-fail")],
      rolling ? `${jobKey}#${job.rolloutIndex}` : "");
    renderVerdicts((job && job.verdicts) || [], jobKey);
    show(document.getElementById("stop-box"), active);
    offer([document.getElementById("stop")], jobKey);
    const cordon = document.getElementById("cordon"), uncordon = document.getElementById("uncordon");
    cordon.hidden = cell.unschedulable;
    uncordon.hidden = !cell.unschedulable;
    offer([cordon], cell.unschedulable ? "" : "cordon");
    offer([uncordon], cell.unschedulable ? "uncordon" : "");
  }

  // The monitor's verdicts can be overruled while their job runs (jobKey: "" when it does not).
  // Each button is kept across renders, so its arming delay runs once, not again at every update.
  const overruleButtons = new Map();
  function renderVerdicts(verdicts, jobKey) {
    const list = document.getElementById("verdicts");
    document.getElementById("verdicts-box").hidden = !verdicts.length;
    const shown = new Set();
    list.replaceChildren(...verdicts.map((v) => {
      const by = v.by === "monitor" ? "by the monitor" + (v.score !== null ? ` (score ${v.score})` : "")
        : `marked by ${v.by || "?"}`;
      const item = el("li", `verdict ${v.outcome}${v.overruled ? " overruled" : ""}`,
        `Rollout ${v.index}${v.total ? "/" + v.total : ""}: ${v.outcome}, ${by}` +
        (v.at ? ` at ${new Date(v.at).toLocaleTimeString()}` : "") +
        (v.overruled ? `, over the monitor's ${v.monitor}${v.score !== null ? ` (score ${v.score})` : ""}` : ""));
      if (jobKey && v.monitor) {
        const action = v.outcome === "success" ? "overrule-fail" : "overrule-success";
        const key = `${jobKey}|${v.request}|${action}`;
        shown.add(key);
        item.append(" ", overruleButton(key, action, v.request));
      }
      return item;
    }));
    for (const key of [...overruleButtons.keys()]) if (!shown.has(key)) overruleButtons.delete(key);
  }
  function overruleButton(key, action, request) {
    let button = overruleButtons.get(key);
    if (button) return button;
    button = el("button", "overrule", action === "overrule-fail" ? "Mark failure" : "Mark success");
    button.type = "button";
    button.dataset.action = action;
    button.addEventListener("click", async () => {
      clearTimeout(armTimers.get(button)); button.disabled = true;
      await act(action, {request});
      disarm(button);
    });
    overruleButtons.set(key, button);
    offer([button], key);
    return button;
  }

  function tickReset() {
    const left = Math.max(0, Math.round((resetDeadline - Date.now()) / 1000));
    const node = document.getElementById("reset-left");
    if (node) node.textContent = `${left} s left before the reset times out.`;
  }

  // The answer goes under the buttons, in their column: in sight of the finger that tapped
  // (within a tablet's first screen), and a long one grows downwards, moving no button.
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
      return response.ok;
    } catch (err) {
      out.textContent = "the FMS did not answer; try again"; out.className = "error";
      return false;
    }
  }

  function wireCellButtons() {
    const confirm = document.getElementById("confirm-reset");
    confirm.addEventListener("click", async () => {
      const request = document.getElementById("reset-box").dataset.request || "";
      confirmedRequest = request;  // one tap, one confirmation: the box hides at once
      show(document.getElementById("reset-box"), false);
      if (!(await act("confirm-reset", {request}))) {
        // Not confirmed: if the reset still waits, its button comes back, and arms again.
        confirmedRequest = ""; offer([confirm], ""); render();
      }
    });
    const rollout = () => document.getElementById("outcome-box").dataset.rollout || "";
    const verdicts = [document.getElementById("mark-success"), document.getElementById("mark-fail")];
    const mark = async (action) => {
      // One tap, one verdict: both buttons wait for the answer, then arm again.
      for (const button of verdicts) { clearTimeout(armTimers.get(button)); button.disabled = true; }
      await act(action, {request: rollout()});
      verdicts.forEach(disarm);
    };
    verdicts[0].addEventListener("click", () => mark("success"));
    verdicts[1].addEventListener("click", () => mark("fail"));
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
