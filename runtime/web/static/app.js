// softplc web: the live page of a running plant (docs/web.md). No inline script: the
// Content-Security-Policy forbids it. Everything below talks to this origin only.
"use strict";

const S = {
  plant: null,          // /api/plant
  user: null,
  mayAct: false,
  names: [], index: new Map(), values: [],
  status: {}, whys: {},
  scan: -1, wall: 0,
  forced: new Set(),
  plotted: [],          // names picked for the timing diagram
  history: [],          // [wall, [values of plotted]] per frame, the last HISTORY
  ws: null, nextId: 1,
  dirty: false,
  frames: 0,
};
const HISTORY = 300;

function $(id) { return document.getElementById(id); }
function el(tag, attrs, text) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
}
function event(text) {
  const li = el("li", {}, new Date().toLocaleTimeString() + "  " + text);
  const list = $("events");
  list.prepend(li);
  while (list.children.length > 200) list.lastChild.remove();
}
function show(v, type) {
  if (v === null || v === undefined) return "?";
  if (type === "time") return (v / 1e9).toFixed(2) + " s";
  if (type === "bool") return v ? "1" : "0";
  return String(v);
}

async function loadPlant() {
  const r = await fetch("/api/plant", {credentials: "same-origin"});
  if (r.status === 401) { S.user = null; S.mayAct = true; showLogin(); return false; }
  const data = await r.json();
  S.plant = data.plant; S.user = data.user; S.mayAct = data.may_act;
  $("plant").textContent = S.plant.plant;
  showLogin();
  const main = $("instances");
  main.replaceChildren();
  for (const inst of S.plant.instances) main.append(await instanceBox(inst));
  return true;
}

function showLogin() {
  $("login").hidden = !S.mayAct || S.user !== null;
  $("who").hidden = S.user === null;
  $("who-name").textContent = S.user ? "acting as " + S.user : "";
  document.body.classList.toggle("act-off", S.user === null);
}

async function instanceBox(inst) {
  const box = el("section", {class: "instance", id: "inst-" + inst.name});
  const h = el("h2", {}, inst.name + " (" + inst.grafcet + ")");
  const quit = el("button", {type: "button", class: "act"}, "SFCQuitError");
  quit.addEventListener("click", () => act("set", inst.name + ".SFCQuitError", "1"));
  h.append(" ", quit);
  box.append(h);
  if (inst.description) box.append(el("p", {}, inst.description));
  const cols = el("div", {class: "columns"});
  const chart = el("div", {class: "chart", "data-instance": inst.name});
  const r = await fetch("/chart/" + encodeURIComponent(inst.name) + ".svg");
  const doc = new DOMParser().parseFromString(await r.text(), "image/svg+xml");
  const svg = document.importNode(doc.documentElement, true);
  for (const g of svg.querySelectorAll("g.step-group")) {
    const rect = g.querySelector("rect.step");
    const x = +rect.getAttribute("x"), y = +rect.getAttribute("y");
    const ns = "http://www.w3.org/2000/svg";
    const tok = document.createElementNS(ns, "circle");
    tok.setAttribute("cx", x + 8); tok.setAttribute("cy", y + 8);
    tok.setAttribute("r", "2.5"); tok.setAttribute("class", "live-token");
    g.append(tok);  // the step's time goes in the drawing's own text.live-t (room kept)
  }
  chart.append(svg);
  const side = el("div", {});
  side.append(el("ul", {class: "why", "data-instance": inst.name}));
  side.append(ioTable(inst));
  cols.append(chart, side);
  box.append(cols);
  return box;
}

function ioTable(inst) {
  const t = el("table", {class: "io"});
  const head = el("tr");
  // a label over every column; the last (force, set) only while acting, as its cells
  for (const c of ["signal", "dir", "point", "value", "forced", "description", "plot"])
    head.append(el("th", {}, c));
  head.append(el("th", {class: "act"}, "act"));
  t.append(head);
  for (const [name, dir, source, descr, type] of inst.io) {
    const tr = el("tr", {"data-name": name, "data-type": type});
    tr.append(el("td", {}, name), el("td", {}, dir), el("td", {}, source),
              el("td", {class: "value"}, "?"), el("td", {class: "forced"}),
              el("td", {}, descr));
    const plot = el("input", {type: "checkbox"});
    plot.addEventListener("change", () => pick(name, plot.checked));
    const pc = el("td"); pc.append(plot); tr.append(pc);
    const a = el("td", {class: "act"});
    if (dir === "memory") {
      const inp = el("input", {size: "5", class: "setval"});
      const b = el("button", {type: "button"}, "set");
      b.addEventListener("click", () => act("set", name, inp.value));
      a.append(inp, b);
    } else if (type === "bool") {
      for (const v of ["0", "1"]) {
        const b = el("button", {type: "button", "data-force": v}, "force " + v);
        b.addEventListener("click", () => act("force", name, v));
        a.append(b);
      }
    } else {
      const inp = el("input", {size: "5", class: "setval"});
      const b = el("button", {type: "button"}, "force");
      b.addEventListener("click", () => act("force", name, inp.value));
      a.append(inp, b);
    }
    const u = el("button", {type: "button", "data-unforce": "1"}, "unforce");
    u.addEventListener("click", () => act("unforce", name));
    a.append(u);
    tr.append(a);
    t.append(tr);
  }
  return t;
}

function pick(name, on) {
  S.plotted = S.plotted.filter((n) => n !== name);
  if (on) S.plotted.push(name);
  S.history = [];
  const c = $("chrono");
  c.height = 20 + 24 * S.plotted.length;
}

function act(action, ...args) {
  if (!S.ws || S.ws.readyState !== WebSocket.OPEN) { event("not connected"); return; }
  const id = S.nextId++;
  S.ws.send(JSON.stringify({act: [id, action, ...args]}));
  event("> " + [action, ...args].join(" "));
}

function connect() {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  const ws = new WebSocket(proto + "//" + location.host + "/ws");
  S.ws = ws;
  ws.addEventListener("message", (m) => onMessage(JSON.parse(m.data)));
  ws.addEventListener("close", () => {
    setLink("lost", "page disconnected");
    if (S.ws === ws) setTimeout(connect, 1000);
  });
}

function setLink(cls, text) {
  const b = $("link");
  b.className = "badge " + cls; b.textContent = text;
  document.body.dataset.link = cls;
  if (cls === "lost") stateUnknown();
}

// Without a link to the controller its state is not known: the page does not go on
// showing the last one (a "running" badge beside a dead controller). The last values stay
// to be read, greyed by app.css (body[data-link=lost]); the state comes back with the
// first status the controller sends once the link is back (onStatus).
function stateUnknown() {
  S.status = {};
  const b = $("state");
  b.className = "badge unknown"; b.textContent = "unknown";
  document.body.dataset.state = "unknown";
  $("fault").textContent = "";
}

function onMessage(m) {
  switch (m.t) {
    case "hello":
      setLink(m.connected ? "live" : "lost", m.connected ? "live" : "no controller");
      break;
    case "f":
      S.names = m.names; S.index = new Map(m.names.map((n, i) => [n, i]));
      S.values = m.values; frame(m);
      setLink("live", "live");
      break;
    case "d":
      for (let i = 0; i < m.changes.length; i += 2) S.values[m.changes[i]] = m.changes[i + 1];
      frame(m);
      break;
    case "s": onStatus(m.status); break;
    case "w": Object.assign(S.whys, m.whys); S.dirty = true; break;
    case "r": event((m.ok ? "< " : "< refused: ") + m.text); break;
    case "n": event("controller: " + m.text); break;
    case "lost": setLink("lost", "no controller"); event("the controller's feed is lost"); break;
    case "schema": event("the plant was reloaded"); loadPlant(); break;
    case "logout":
      event("logged out: " + m.why); S.user = null; showLogin(); break;
  }
}

function onStatus(st) {
  const before = S.status;
  S.status = st;
  if (before.state !== st.state) event("state " + st.state + (st.fault ? " (" + st.fault + ")" : ""));
  const forced = new Set(st.forced || []);
  for (const n of forced) if (!S.forced.has(n)) event("forced " + n);
  for (const n of S.forced) if (!forced.has(n)) event("released " + n);
  S.forced = forced;
  const b = $("state");
  b.className = "badge " + st.state; b.textContent = st.state;
  document.body.dataset.state = st.state;
  $("fault").textContent = st.fault || "";
  $("cycle").textContent = "cycle " + st.cycle_ms + " ms";
  const l = st.lateness_us;
  $("lateness").textContent = l ? "late p50 " + l.p50 + " p99 " + l.p99 + " max " + l.max + " µs" : "";
  $("overruns").textContent = "overruns " + st.overruns;
  $("drivers").textContent = Object.entries(st.drivers || {})
    .map(([n, d]) => n + " " + d[0] + (d[1] ? " (" + d[1] + ")" : "")).join(", ");
  S.dirty = true;
}

function frame(m) {
  S.scan = m.scan; S.wall = m.wall; S.frames++;
  if (S.plotted.length) {
    S.history.push([m.wall, S.plotted.map((n) => S.values[S.index.get(n)])]);
    if (S.history.length > HISTORY) S.history.shift();
  }
  S.dirty = true;
  render();
}

function stepTime(s) {
  // at most "9999.9 s" or "9999 min": the room the drawing keeps for it (LIVE_TIME_W)
  if (s < 1e4) return s.toFixed(1) + " s";
  if (s < 6e5) return (s / 60).toFixed(0) + " min";
  return (s / 3600).toFixed(0) + " h";
}

function value(name) { const i = S.index.get(name); return i === undefined ? null : S.values[i]; }

function render() {
  if (!S.dirty || !S.plant) return;
  S.dirty = false;
  document.body.dataset.scan = S.scan;
  document.body.dataset.frames = S.frames;
  for (const inst of S.plant.instances) {
    const box = $("inst-" + inst.name);
    if (!box) continue;
    for (const g of box.querySelectorAll("g.step-group")) {
      const step = g.dataset.step;
      const on = !!value(inst.name + "." + step + ".X");
      if (on && !g.classList.contains("active")) g.dataset.shownScan = S.scan;
      g.classList.toggle("active", on);
      const t = value(inst.name + "." + step + ".T");
      g.querySelector(".live-t").textContent = on && t !== null ? stepTime(t / 1e9) : "";
    }
    renderWhy(inst, box);
    for (const tr of box.querySelectorAll("table.io tr[data-name]")) {
      const n = tr.dataset.name;
      tr.querySelector("td.value").textContent = show(value(n), tr.dataset.type);
      tr.classList.toggle("forced", S.forced.has(n));
    }
  }
  drawChrono();
}

function renderWhy(inst, box) {
  const why = S.whys[inst.name] || [];
  const ul = box.querySelector("ul.why");
  ul.replaceChildren();
  const marks = new Map();
  for (const [step, tns, transitions] of why) {
    // the why follows the frames (explained every 100 ms, instance by instance): a step
    // the shown frame no longer has active is not listed nor its transitions marked
    if (!value(inst.name + "." + step + ".X")) continue;
    for (const [index, cond, blocked, terms] of transitions) {
      const blocking = blocked.length > 0 || !cond;
      marks.set(String(index), cond && !blocked.length ? "true" : "blocking");
      const li = el("li", {class: blocking ? "blocking" : ""});
      const t = inst.transitions.find((x) => x[0] === index);
      let text = step + " (" + (tns / 1e9).toFixed(1) + " s) → when " + (t ? t[1] : index) +
        ": " + (cond ? "true" : "false");
      if (blocked.length) text += "; " + blocked.join("; ");
      const falseTerms = terms.filter((x) => x[1] === 1 && !x[2]).map((x) => x[0]);
      if (!cond && falseTerms.length) text += "; waits for " + falseTerms.join(", ");
      li.textContent = text;
      ul.append(li);
    }
  }
  for (const g of box.querySelectorAll("g.transition-group")) {
    const m = marks.get(g.dataset.transition);
    g.classList.toggle("true", m === "true");
    g.classList.toggle("blocking", m === "blocking");
  }
}

function drawChrono() {
  const c = $("chrono");
  const ctx = c.getContext("2d");
  ctx.clearRect(0, 0, c.width, c.height);
  if (!S.plotted.length || S.history.length < 2) return;
  const t0 = S.history[0][0], t1 = S.history[S.history.length - 1][0];
  const x0 = 160, w = c.width - x0 - 10, span = Math.max(t1 - t0, 1e-3);
  ctx.font = "12px sans-serif";
  S.plotted.forEach((name, k) => {
    const y = 10 + 24 * k, hgt = 16;
    ctx.fillStyle = "#111"; ctx.fillText(name, 4, y + 12);
    let lo = Infinity, hi = -Infinity;
    for (const [, v] of S.history) { const x = +v[k]; if (x < lo) lo = x; if (x > hi) hi = x; }
    const scale = hi > lo ? hi - lo : 1;
    ctx.strokeStyle = "#1565c0"; ctx.beginPath();
    S.history.forEach(([tw, v], i) => {
      const x = x0 + w * (tw - t0) / span;
      const yy = y + hgt - hgt * ((+v[k]) - (hi > lo ? lo : 0)) / scale;
      if (i === 0) ctx.moveTo(x, yy); else ctx.lineTo(x, yy);
    });
    ctx.stroke();
  });
}

async function login(ev) {
  ev.preventDefault();
  const r = await fetch("/api/login", {
    method: "POST", credentials: "same-origin",
    headers: {"Content-Type": "application/json"},
    body: JSON.stringify({user: $("user").value, password: $("password").value}),
  });
  const data = await r.json().catch(() => ({error: "refused"}));
  $("password").value = "";
  if (!data.ok) { $("login-error").textContent = data.error; event("login refused"); return; }
  $("login-error").textContent = "";
  event("logged in as " + data.user);
  await restart();
}

async function logout() {
  await fetch("/api/logout", {method: "POST", credentials: "same-origin",
                              headers: {"Content-Type": "application/json"}, body: "{}"});
  await restart();
}

async function restart() {
  // the page's WebSocket carries the login it was opened with: open a new one
  const old = S.ws; S.ws = null;
  if (old) old.close();
  if (await loadPlant()) connect();
}

window.addEventListener("DOMContentLoaded", async () => {
  $("login").addEventListener("submit", login);
  $("logout").addEventListener("click", logout);
  $("pause").addEventListener("click", () => act("pause"));
  $("resume").addEventListener("click", () => act("resume"));
  $("cycle").addEventListener("click", () => act("cycle", $("cycles").value));
  $("ack").addEventListener("click", () => act("ack"));
  if (await loadPlant()) connect();
});
