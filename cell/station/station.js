// Operator station: polls /api/state, draws the frame with outlines and the proposed grasp
// (SVG in image pixel coordinates: origin at the top-left pixel's top-left corner, u right,
// v down), and posts commands with the session token (X-Cell-Token).
"use strict";

const SVGNS = "http://www.w3.org/2000/svg";
const POLL_MS = 300;
const OFFLINE_POLL_MS = 1000;
// A cell that does not answer within this is taken for one that does not answer (stopped, hung, its terminal
// paused): a request alone waits as long as the connection stays open, and the page went on showing a green
// "running" a minute after the station's process was stopped
const STATE_TIMEOUT_MS = 5000;
const COMMAND_TIMEOUT_MS = 10000;

function fetchWithin(url, options, ms) {
  const ctl = new AbortController();
  const timer = setTimeout(() => ctl.abort(), ms);
  return fetch(url, {...options, signal: ctl.signal}).finally(() => clearTimeout(timer));
}

function noAnswer(e, ms) {
  return e && e.name === "AbortError" ? "no answer within " + (ms / 1000) + " s" : String(e);
}
const $ = (id) => document.getElementById(id);

let token = "";
let tokenSession = null;    // the station's session the token was first used in
let session = null;         // the station's session (new at each start) whose state is shown
let last = null;            // last state received
let frameIndex = null;      // index of the frame shown
let teach = null;           // null, or {stage: "part" | "p1" | "p2", part, p1, frame (its index), note}
let approvalPending = false; // the approve-each box was toggled and the cell has not answered yet
let zoom = false;           // show the parts' surroundings magnified rather than the whole frame
let proposalKey = null;     // the pending proposal the reason field was typed for
let decidedNo = null;       // the proposal_no this page sent a decision for: no second one for it

// ---- token: from the URL fragment (#token=...), kept for this tab only, removed from the URL
function loadToken() {
  const m = /(?:^#|&)token=([^&]+)/.exec(location.hash);
  if (m) {
    setToken(decodeURIComponent(m[1]));
    history.replaceState(null, "", location.pathname + location.search);
  } else {
    token = sessionStorage.getItem("cell-token") || "";
    tokenSession = sessionStorage.getItem("cell-token-session");
  }
  $("token-card").classList.toggle("hidden", !!token);
}

// A token given now belongs to the session the page sees next
function setToken(t) {
  token = t;
  tokenSession = null;
  sessionStorage.setItem("cell-token", token);
  sessionStorage.removeItem("cell-token-session");
}

// Each start of the station is a session with an id of its own. A page left open across a restart
// says so, and forgets what it held of the old session (the frame's number, a teach begun, a decision
// sent); the old session's token is remembered, to explain a refusal of it.
function noteSession(id) {
  if (!id) return;
  if (token && !tokenSession) {
    tokenSession = id;
    sessionStorage.setItem("cell-token-session", id);
  }
  if (session !== null && id !== session) {
    frameIndex = null;
    $("frame").removeAttribute("src");  // the old session's picture is not this cell's tray
    teach = null;
    decidedNo = null;
    $("log").dataset.newest = "";
    toast("the station was restarted: this page shows its new state now");
  }
  session = id;
}

function askForToken() {
  $("token-card").classList.remove("hidden");
  $("token").focus();
}

function toast(text, ok) {
  const t = $("toast");
  t.textContent = text;
  t.classList.toggle("ok", !!ok);
  t.classList.remove("hidden");
  clearTimeout(toast.timer);
  // long enough to read: about 60 ms a character; at least 1.5 s for good news, 5 s for a refusal
  toast.timer = setTimeout(() => t.classList.add("hidden"), Math.max(ok ? 1500 : 5000, 60 * text.length));
}

// ---- talking to the cell
async function post(cmd, body) {
  if (!token) {
    askForToken();
    toast("enter the station token first");
    return null;
  }
  try {
    const headers = {"Content-Type": "application/json", "X-Cell-Token": token};
    if (session) headers["X-Cell-Session"] = session;  // a station started since refuses the command (409)
    const r = await fetchWithin("/api/" + cmd, {method: "POST", headers, body: JSON.stringify(body || {})},
                                COMMAND_TIMEOUT_MS);
    const data = await r.json().catch(() => ({ok: false, error: "HTTP " + r.status}));
    const tokenIsOld = !!tokenSession && !!data.session && data.session !== tokenSession;
    // (a restarted station's session is taken on when its state is drawn, not from a refusal: until then a
    // second press still names the old session and is refused too, not applied to a grasp not yet shown)
    if (r.status === 403 && /token/.test(data.error || "")) {
      askForToken();
      // the server's words are for scripts (a header's name); the operator needs what to do
      data.error = (tokenIsOld
        ? "this page's token is from before the station restarted, and no longer valid: open the new link "
          + "the cell printed, "
        : "this page has no valid token (was the cell restarted?): open the link the cell printed, ")
        + "or enter the token it printed; nothing was done";
    }
    if (!data.ok) {
      toast(data.error || ("HTTP " + r.status));
      return null;
    }
    if (data.state_error) {  // done, but the state to show with it could not be made
      toast(cmd + ": done; " + data.state_error, true);
      return data;
    }
    if (!olderThanShown(data)) render(data);  // a poll answered after it may be newer
    return data;
  } catch (e) {
    toast("the cell does not answer: " + noAnswer(e, COMMAND_TIMEOUT_MS) + " (" + cmd + " may not have been done)");
    return null;
  }
}

// A state older than the one shown: a poll asked before a command's answer came (it would flip the page
// back, e.g. to "awaiting approval" with Approve live after Stop), or a slow command's answer overtaken
// by a poll. The control's seq counts its changes; each start of the station counts anew.
function olderThanShown(data) {
  return !!last && data.session === last.session && data.control.seq < last.control.seq;
}

async function poll() {
  let answered = true;
  try {
    const r = await fetchWithin("/api/state", {cache: "no-store"}, STATE_TIMEOUT_MS);
    if (!r.ok) {  // the cell is there but cannot say its state: the last one shown would be a lie
      let why = "HTTP " + r.status;
      try { why += ": " + (await r.json()).error; } catch (_) { /* not JSON: the status says enough */ }
      answered = false;
      offline("the cell cannot report its state (" + why + "); commands are off until it can");
    } else {
      const data = await r.json();
      if (data && !olderThanShown(data)) render(data);  // also while a command is on its way
    }
  } catch (e) {
    answered = false;
    offline(e && e.name === "AbortError"
      ? "the cell does not answer (" + noAnswer(e, STATE_TIMEOUT_MS) + "): it may be stopped or hung; see its terminal"
      : undefined);
  }
  // while the cell does not answer, once a second: each refused connection is an error line in the
  // browser's console (three a second filled it), and a second is soon enough to see it back
  setTimeout(poll, answered ? POLL_MS : OFFLINE_POLL_MS);
}

// The station is gone (the run ended, the cell was shut down): say so, and offer no command
// until it answers again (the last state received would be a lie: a green "running").
function offline(why) {
  const badge = $("state");
  badge.textContent = "offline";
  badge.className = "badge state-offline";
  document.title = "offline · Cell station";
  const ended = last && last.control && ["done", "stopped"].includes(last.control.state);
  $("message").textContent = why ? why : ended
    ? "the run is " + last.control.state + " and the cell closed the station (the summary is in the cell's terminal)"
    : "the cell does not answer (the run may have ended: see the cell's terminal)";
  for (const b of document.querySelectorAll(".panel button:not(#btn-token)")) b.disabled = true;
  // Stop always tries: a cell that cannot report its state may still take it (it did, while the page
  // greyed it out), and a second stop is harmless; where nobody answers, the toast says so
  $("btn-stop").disabled = false;
  $("approve-each").disabled = true;
  $("view").classList.add("stale");
  const fault = $("fault");  // nothing can be reset now: say what the fault was, not what to do
  if (last && last.control && last.control.fault) {
    const f = last.control.fault;
    fault.textContent = (f.asking ? "The last stop, " + f.source + " needed you: " : "The last fault, in " + f.source + ": ")
      + f.why;
    fault.classList.add("past");
  }
  frameIndex = null;  // a station started again may have a frame of the same number: load it anew
  teach = null;
  drawTeach();
  fitView();
}

// ---- drawing
function el(name, attrs, parent) {
  const e = document.createElementNS(SVGNS, name);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
  if (parent) parent.appendChild(e);
  return e;
}
const ptsAttr = (pts) => pts.map((p) => p[0] + "," + p[1]).join(" ");

function render(data) {
  noteSession(data.session);
  last = data;
  const c = data.control, cell = data.cell || {};
  const badge = $("state");
  badge.textContent = c.state.replace("_", " ");
  badge.className = "badge state-" + c.state;
  document.title = c.state.replace("_", " ") + " · Cell station";  // a tab in the background shows it too
  const after = c.state === "awaiting_approval" ? afterDecision(c.events || []) : "";
  $("message").textContent = c.message + (after ? " — then " + after : "") + (c.ended ? " — " + c.ended : "");
  const cur = c.current || {}, sum = c.summary || {};
  // when done, the last part's move is over: say what the run removed instead
  $("current").textContent = c.state === "done"
    ? (sum.parts_removed != null ? "removed " + sum.parts_removed + (sum.parts_total != null ? " of " + sum.parts_total : "")
       + ((sum.parts_total ?? sum.parts_removed) === 1 ? " part" : " parts") : "")
    : (cur.part ? "part " + cur.part : "") + (cur.step != null ? " · step " + cur.step : "")
      + (c.checkpoint ? " · at " + c.checkpoint : "");
  const fault = $("fault");
  fault.classList.toggle("hidden", !c.fault);
  fault.classList.remove("past");
  if (c.fault) {
    fault.textContent = (c.fault.asking ? "STOPPED TO ASK — " + c.fault.source + " needs you: "
      : "FAULT in " + c.fault.source + ": ") + c.fault.why
      + (c.state === "fault" && !c.ended ? " — fix it, then Reset" : " — the sequence is " + c.state.replace("_", " "));
  }

  // buttons: enabled only where the state allows the command
  const s = c.state, live = ["idle", "paused", "running", "awaiting_approval"].includes(s);
  $("btn-run").disabled = !(s === "idle" || s === "paused" || (s === "running" && c.step_mode)
                            || (s === "awaiting_approval" && !!after));  // Run takes the pending pause back
  $("btn-pause").disabled = !(s === "running" || (s === "awaiting_approval" && !after));
  $("btn-step").disabled = !live;
  $("btn-stop").disabled = !(live || s === "fault");  // in a fault: abandon the sequence, nothing moves
  const decidable = s === "awaiting_approval" && c.proposal_no !== decidedNo;  // one decision per grasp
  $("btn-approve").disabled = !decidable;
  $("btn-reject").disabled = !decidable;
  $("btn-reset").disabled = !["fault", "stopped", "done"].includes(s) || !!c.ended;  // no loop left to reset
  $("btn-teach").disabled = !teach && !(cell.parts || []).length;  // nothing on the frame to teach on
  $("view").classList.remove("stale");
  const ae = $("approve-each");
  ae.disabled = false;
  if (!approvalPending) ae.checked = !!c.require_approval;  // the cell's, also when focused

  const p = c.proposal;
  // a reason typed for one grasp is not kept for the next one ('r' would reject that at once)
  const pkey = p ? JSON.stringify(p) : "";
  if (proposalKey !== null && pkey !== proposalKey) { $("reason").value = ""; askReason(false); }
  proposalKey = pkey;
  $("proposal-card").classList.toggle("awaiting", s === "awaiting_approval");
  $("proposal-text").textContent = p ? proposalText(p) : "none";
  const ex = cell.examples;
  $("examples").textContent = ex ? ex.count + (ex.count === 1 ? " example in " : " examples in ") + ex.path
    + (ex.new_to ? "; new ones go to " + ex.new_to : "") : "";

  drawFrame(cell.frame || {});
  drawParts(cell.parts || [], p ? p.target : null);
  drawProposal(cell.proposal_px);
  drawLog(c.events || []);
  drawTeach();
}

// What a Pause or Step pressed while a grasp waits will do after the decision (the state stays
// "awaiting approval" until then; the page showed no sign of the press): the last of pause, step,
// run since the proposal, from the event log.
function afterDecision(events) {
  for (let i = events.length - 1; i >= 0; i--) {
    const e = events[i];
    if (e.event === "proposal") return "";
    if (e.event === "run") return "";
    if (e.event === "pause") return "pause";
    if (e.event === "step") return "pause at the next checkpoint";
  }
  return "";
}

function proposalText(p) {
  const lines = ["target    " + p.target];
  if (p.opening_mm != null) lines.push("opening   " + p.opening_mm + " mm");
  if (p.angle_deg != null) lines.push("axis      " + p.angle_deg + "°");
  if (p.grasp_z_mm != null) lines.push("grasp z   " + p.grasp_z_mm + " mm");
  if (p.contacts) lines.push("contacts  " + p.contacts.map((c) => c.map((v) => (+v).toFixed(1)).join(", ")).join("  ·  "));
  if (p.joints) lines.push("joints    " + Object.values(p.joints).join(" / "));
  if (p.how) lines.push("(" + p.how + ")");
  return lines.join("\n");
}

function drawFrame(f) {
  const svg = $("overlay");
  if (f.width_px && f.height_px) {
    const [x, y, w, h] = shownBox(f);
    svg.setAttribute("viewBox", x + " " + y + " " + w + " " + h);
    $("view").style.aspectRatio = f.width_px + " / " + f.height_px;
    const img = $("frame").style;  // the picture cropped and scaled exactly as the overlay
    img.width = (100 * f.width_px / w) + "%";
    img.height = (100 * f.height_px / h) + "%";
    img.left = (-100 * x / w) + "%";
    img.top = (-100 * y / h) + "%";
  }
  fitView();
  $("frameno").textContent = f.index == null ? "–" : f.index;
  $("noframe").classList.toggle("hidden", f.index != null);
  if (f.index == null && frameIndex != null) {  // no frame (yet): no picture, not the last one under the notice
    frameIndex = null;
    $("frame").removeAttribute("src");
  }
  if (f.index != null && f.index !== frameIndex) {
    // a part chosen or a contact clicked on the last frame is not where it is on this one
    if (frameIndex != null && teach && teach.stage !== "part") {
      teach = {stage: "part", note: "Teach: a new frame came in; click the part again"};
    }
    frameIndex = f.index;
    // the session in the address too: a restarted station's frame 0 is not the old one's (the browser kept
    // showing the old picture under the new outlines, the same address)
    $("frame").src = "/api/frame.png?s=" + encodeURIComponent(session || "") + "&i=" + f.index;
  }
}

// The part of the frame shown: all of it, or with Zoom the parts on it (and the proposed grasp) with
// a margin, at the frame's own aspect ratio (the layout stays, the tray is magnified): a part of
// 40 px in a 1280 px frame is big enough to put a contact on with a finger. The overlay's viewBox is
// that box, so clicks and marks stay in image px.
function shownBox(f) {
  const W = f.width_px, H = f.height_px, cell = (last && last.cell) || {};
  const pts = [];
  for (const part of cell.parts || []) pts.push(...part.outline_px);
  const pp = cell.proposal_px;
  if (pp) for (const poly of [pp.palm_px || [], ...(pp.fingers_px || [])]) pts.push(...poly);
  if (!zoom || !pts.length) return [0, 0, W, H];
  const us = pts.map((q) => q[0]), vs = pts.map((q) => q[1]);
  const u0 = Math.min(...us), u1 = Math.max(...us), v0 = Math.min(...vs), v1 = Math.max(...vs);
  const w = Math.min(W, Math.max(W / 8, 1.3 * Math.max(u1 - u0, (v1 - v0) * W / H))), h = w * H / W;
  const x = Math.min(Math.max(0, (u0 + u1 - w) / 2), W - w), y = Math.min(Math.max(0, (v0 + v1 - h) / 2), H - h);
  return [x, y, w, h].map((a) => Math.round(a * 10) / 10);
}

function toggleZoom() {
  zoom = !zoom;
  $("btn-zoom").classList.toggle("active", zoom);
  $("btn-zoom").setAttribute("aria-pressed", String(zoom));
  if (last) render(last);
}

// The frame as wide as its column, but never taller than the window has room for below what is
// above it (the header, two lines of it when the message is long, the fault banner) and above the
// hint line: the whole tray is seen without scrolling. Stacked under a portrait screen's header, at
// most 55 % of the height, so the buttons below it stay on the screen too.
function fitView() {
  const view = $("view"), f = (last && last.cell && last.cell.frame) || {};
  const ratio = f.width_px && f.height_px ? f.width_px / f.height_px : 640 / 512;
  const top = view.getBoundingClientRect().top + window.scrollY;
  const below = $("hint").getBoundingClientRect().height + 6 + 16;  // the hint, its margin, main's padding
  let room = window.innerHeight - top - below;
  const stacked = getComputedStyle($("main")).flexDirection === "column";
  if (stacked) room = Math.min(room, 0.55 * window.innerHeight);
  const width = Math.max(160, Math.floor(room * ratio));
  view.style.maxWidth = width + "px";
  // side by side, the column is no wider than the frame: the panel sits next to it and takes what is
  // left up to its maximum (on a wide screen a gap of 380 px opened between the frame and the buttons)
  view.parentElement.style.flexBasis = stacked ? "" : width + 2 + "px";
  // the log takes the height left under the other cards, so the page itself does not scroll
  // (scrolling it moved the frame and the buttons away); 90 px at least: then the page scrolls
  const logCard = document.querySelector(".log-card");
  const logTop = logCard.getBoundingClientRect().top + window.scrollY;
  logCard.style.maxHeight = Math.max(90, Math.floor(window.innerHeight - logTop - 16)) + "px";
}

// Image px per screen px: marks and labels keep their size on the screen whatever the frame's
// size (the cell's 1280 x 1024 frame is drawn at about half size).
function pxPerScreenPx() {
  const svg = $("overlay"), w = svg.getBoundingClientRect().width;
  return w > 0 ? svg.viewBox.baseVal.width / w : 1;
}

// Redrawn only when something drawn changed: replacing the polygons at every poll made a slow tap
// on a part (pressed across a redraw) no click at all. Teach picks the part by where the tap lands
// (partAt), not by which element got it.
function drawParts(parts, target) {
  const g = $("parts"), k = pxPerScreenPx();
  const selected = teach && teach.part;
  const key = JSON.stringify([parts, target, selected, Math.round(k * 1000)]);
  if (g.dataset.key === key) return;
  g.dataset.key = key;
  g.replaceChildren();
  for (const part of parts) {
    const cls = "part" + (part.id === target ? " target" : "") + (selected === part.id ? " selected" : "");
    el("polygon", {points: ptsAttr(part.outline_px), class: cls, "data-part": part.id}, g);
    const [u, v] = centroid(part.outline_px);
    el("text", {x: u, y: v, class: "part-label", "text-anchor": "middle", "font-size": 14 * k,
                "stroke-width": 3 * k}, g).textContent = part.id;
  }
}

function drawProposal(pp) {
  const g = $("proposal");
  g.replaceChildren();
  if (!pp) return;
  if (pp.palm_px) el("polygon", {points: ptsAttr(pp.palm_px), class: "palm"}, g);
  for (const f of pp.fingers_px || []) el("polygon", {points: ptsAttr(f), class: "finger"}, g);
  const cs = pp.contacts_px || [];
  if (cs.length === 2) el("line", {x1: cs[0][0], y1: cs[0][1], x2: cs[1][0], y2: cs[1][1], class: "axis"}, g);
  const k = pxPerScreenPx();
  for (const q of cs) el("circle", {cx: q[0], cy: q[1], r: 5 * k, class: "contact"}, g);
}

function drawLog(events) {
  const ol = $("log");
  const newest = events.length ? events[events.length - 1].n : 0;
  if (ol.dataset.newest === String(newest)) return;
  ol.dataset.newest = String(newest);
  ol.replaceChildren();
  for (const e of events.slice().reverse()) {
    const li = document.createElement("li");
    const t = clock(e.t);
    const ev = document.createElement("span");
    ev.className = "ev ev-" + e.event;
    ev.textContent = e.event;
    li.append(t + " ", ev, " " + (e.message || ""));
    ol.appendChild(li);
  }
}

// The event's time (UTC in the log) on the station PC's clock, as the operator's watch reads it
function clock(iso) {
  const d = new Date(iso || "");
  return isNaN(d) ? "" : d.toLocaleTimeString("en-GB", {hour12: false});
}

function centroid(pts) {
  let u = 0, v = 0;
  for (const p of pts) { u += p[0]; v += p[1]; }
  return [u / pts.length, v / pts.length];
}

// ---- teach: click a part, then two contact points on its edge
function drawTeach() {
  const g = $("teachmarks");
  g.replaceChildren();
  $("view").classList.toggle("teaching", !!teach);
  $("btn-teach").classList.toggle("active", !!teach);
  const st = $("teach-status"), hint = $("teach-hint");
  $("keys").classList.toggle("hidden", !!teach);  // the prompt goes under the frame, where the clicks go
  if (!teach) { st.textContent = hint.textContent = ""; return; }
  if (teach.p1) el("circle", {cx: teach.p1[0], cy: teach.p1[1], r: 6 * pxPerScreenPx(), class: "teachmark"}, g);
  st.textContent = teach.stage === "part" ? (teach.note || "Teach: click the part to grasp")
    : teach.stage === "p1" ? "Teach " + teach.part + ": click the first contact on its edge"
    : "Teach " + teach.part + ": click the second contact";
  hint.textContent = st.textContent + " · Esc cancels";
}

function framePoint(ev) {
  // screen -> SVG user units, which are image pixels (viewBox = frame size)
  const svg = $("overlay");
  const pt = svg.createSVGPoint();
  pt.x = ev.clientX; pt.y = ev.clientY;
  const q = pt.matrixTransform(svg.getScreenCTM().inverse());
  return [Math.round(q.x * 10) / 10, Math.round(q.y * 10) / 10];
}

// The part under image point q: inside its outline (the topmost, drawn last, first), else the one
// whose edge is nearest within a fingertip (12 screen px): a tap on the edge counts.
function partAt(q) {
  const parts = (last && last.cell && last.cell.parts) || [];
  for (let i = parts.length - 1; i >= 0; i--) if (inside(q, parts[i].outline_px)) return parts[i].id;
  let best = null, bestD = 12 * pxPerScreenPx();
  for (const part of parts) {
    const dd = edgeDistance(q, part.outline_px);
    if (dd <= bestD) { best = part.id; bestD = dd; }
  }
  return best;
}

function inside(q, pts) {
  let c = false;
  for (let i = 0, j = pts.length - 1; i < pts.length; j = i++) {
    const [ui, vi] = pts[i], [uj, vj] = pts[j];
    if ((vi > q[1]) !== (vj > q[1]) && q[0] < (uj - ui) * (q[1] - vi) / (vj - vi) + ui) c = !c;
  }
  return c;
}

function edgeDistance(q, pts) {
  let best = Infinity;
  for (let i = 0, j = pts.length - 1; i < pts.length; j = i++) {
    const [au, av] = pts[j], [bu, bv] = pts[i], du = bu - au, dv = bv - av;
    const t = Math.max(0, Math.min(1, ((q[0] - au) * du + (q[1] - av) * dv) / (du * du + dv * dv || 1)));
    best = Math.min(best, Math.hypot(q[0] - au - t * du, q[1] - av - t * dv));
  }
  return best;
}

async function onFrameClick(ev) {
  if (!teach) return;
  const p = framePoint(ev);
  if (teach.stage === "part") {
    const id = partAt(p);
    if (id == null) { teach.note = "Teach: no part there; click inside a part's outline"; drawTeach(); return; }
    teach = {stage: "p1", part: id, frame: frameIndex};
    if (last) render(last);
    return;
  }
  if (teach.stage === "p1") {
    teach = {stage: "p2", part: teach.part, p1: p, frame: teach.frame};
    drawTeach();
    return;
  }
  const t = teach;
  teach = null;
  drawTeach();
  // the frame the clicks were on: the cell refuses them (409) on a later one, where the part may have moved
  const r = await post("teach", {part: t.part, p1_px: t.p1, p2_px: p, frame: t.frame});
  if (r) {
    toast("taught " + t.part + ": example " + r.result.example_id
      + " (" + r.result.n_examples + " examples)", true);
  } else if (!teach && frameIndex === t.frame) {
    // refused (a contact off the edge, too wide for the jaws: the toast says why): the same part,
    // click its contacts again, rather than Teach and the part all over
    teach = {stage: "p1", part: t.part, frame: t.frame};
    redrawTeach();
  }
}

// The teaching state changed: the whole page where a state came in (the selected part is drawn
// with the parts), else the teach marks alone
function redrawTeach() {
  if (last) render(last); else drawTeach();
}

function startTeach() {
  teach = teach ? null : {stage: "part"};
  redrawTeach();
}

function cancelTeach() {
  if (!teach) return;
  teach = null;
  redrawTeach();
}

// Reject with an empty reason asks for one first (the reason is what the invalid example teaches);
// a second Reject (or Enter in the empty field) rejects without one.
const REASON_HINT = "reason for rejecting";
const REASON_ASK = "why? Enter rejects · Reject again: none";

function reject() {
  const field = $("reason"), reason = field.value.trim();
  if (!reason && !field.classList.contains("ask")) {
    askReason(true);
    field.focus();
    return Promise.resolve(null);
  }
  askReason(false);
  return decide("reject", {reason}).then((r) => { if (r) field.value = ""; });
}

// Approve and Reject name the grasp drawn on the page (its proposal_no, and the proposal itself): the
// cell refuses them (409) when another grasp waits by now (a page a poll behind would decide the next
// grasp unseen), and answers a repeat of the decision (a double tap) as done. From the first tap on,
// both buttons are off for that grasp, so the second tap of a double tap sends nothing.
async function decide(cmd, body) {
  const c = (last && last.control) || {};
  decidedNo = c.proposal_no ?? null;
  $("btn-approve").disabled = $("btn-reject").disabled = true;
  // (undefined: not sent)
  const r = await post(cmd, {...body, proposal: c.proposal || undefined, proposal_no: c.proposal_no ?? undefined});
  if (!r) {  // not taken (refused, no answer): the grasp may be decided again
    decidedNo = null;
    if (last) render(last);
  }
  return r;
}

// The grasp drawn was decided from this page: a second Approve or Reject for it is nothing, quietly
function decisionSent(id) {
  return (id === "btn-approve" || id === "btn-reject") && decidedNo != null && !!last
    && last.control.proposal_no === decidedNo;
}

function askReason(on) {
  const field = $("reason");
  field.classList.toggle("ask", on);
  field.placeholder = on ? REASON_ASK : REASON_HINT;
}

// ---- keyboard: space step, s stop, p pause, a approve, r reject, t teach, Esc cancels teaching.
// Each key does what its button does, and only when that button is enabled (no command the state
// cannot take, none while the cell is offline). Never with Ctrl/Alt/Meta (Ctrl+A, Ctrl+R, Ctrl+P are
// the browser's: select all must not approve a grasp), never while typing in a text field, once per
// press (a held key does not repeat the command).
const KEY_BUTTONS = {" ": "btn-step", "s": "btn-stop", "p": "btn-pause", "a": "btn-approve", "r": "btn-reject",
                     "t": "btn-teach", "z": "btn-zoom"};

function onKey(ev) {
  if (ev.ctrlKey || ev.metaKey || ev.altKey || ev.isComposing) return;
  const t = ev.target;
  // Esc cancels a teach wherever the focus is (the hint says so; typed into the reason, it did nothing)
  if (ev.key === "Escape" && teach) { cancelTeach(); return; }
  if (t.isContentEditable || t.tagName === "TEXTAREA" || t.tagName === "SELECT") return;
  if (t.tagName === "INPUT" && t.type !== "checkbox") return;  // the reason, the token
  if (ev.key === "Escape") { cancelTeach(); return; }
  if (ev.key === " " && t.tagName === "INPUT") return;  // space toggles the focused checkbox, as usual
  // space and Enter press the focused button, as usual (space on a focused Stop stepped the cell on)
  if ((ev.key === " " || ev.key === "Enter") && t.tagName === "BUTTON") return;
  const key = ev.key.length === 1 ? ev.key.toLowerCase() : ev.key;
  const id = KEY_BUTTONS[key];
  if (!id) return;
  ev.preventDefault();  // no scrolling, no click of a focused button, no "r" typed into the reason
  if (ev.repeat) return;
  const b = $(id);
  if (b.disabled) {
    if (decisionSent(id)) return;
    toast(b.textContent.replace(/^\W+/, "") + " is not available now (" + $("state").textContent + ")");
    return;
  }
  if (id === "btn-reject" && !$("reason").value.trim()) { askReason(true); $("reason").focus(); return; }
  b.click();
}

// ---- wiring
function init() {
  loadToken();
  for (const b of document.querySelectorAll("button[data-cmd]")) {
    b.addEventListener("click", () => post(b.dataset.cmd));
  }
  $("btn-reject").addEventListener("click", reject);
  $("btn-approve").addEventListener("click", () => decide("approve", {}));
  $("btn-teach").addEventListener("click", startTeach);
  $("btn-zoom").addEventListener("click", toggleZoom);
  $("overlay").addEventListener("click", onFrameClick);
  $("approve-each").addEventListener("change", async (ev) => {
    approvalPending = true;
    const r = await post("approval", {required: ev.target.checked});
    approvalPending = false;
    if (r && !r.control.require_approval && r.control.state === "awaiting_approval") {
      toast("approve each grasp: off from the next grasp; the one waiting still needs Approve or Reject", true);
    }
    // refused (a wrong token, the cell gone): show the cell's setting, not the click
    if (!r && last) ev.target.checked = !!last.control.require_approval;
  });
  const useToken = () => {
    setToken($("token").value.trim());
    $("token-card").classList.toggle("hidden", !!token);
  };
  $("btn-token").addEventListener("click", useToken);
  $("token").addEventListener("keydown", (ev) => { if (ev.key === "Enter") useToken(); });
  $("reason").addEventListener("keydown", (ev) => { if (ev.key === "Enter") reject(); });
  $("frame").addEventListener("load", () => $("noframe").classList.add("hidden"));
  window.addEventListener("resize", () => { fitView(); if (last) render(last); });
  document.addEventListener("keydown", onKey);
  poll();
}

document.addEventListener("DOMContentLoaded", init);
