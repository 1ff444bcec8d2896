"""The HTML/JS template of ``regrasp view`` (see `planner.view`).

Placeholders: ``/*TITLE*/``, ``/*MESHCAT_JS*/`` (meshcat's viewer bundle, three.js inside),
``/*COMMANDS*/`` (base64 msgpack scene commands), ``/*DATA*/`` (states, steps, frames).
The panel's timeline is ``<ol id="regrasp-timeline">`` with one ``li.state`` per plan state
and one ``li.step`` per step; ``body[data-ready]`` is set once the scene is built.
"""

PAGE = r"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>/*TITLE*/</title>
<style>
  body { margin: 0; font: 13px/1.35 system-ui, -apple-system, "Segoe UI", sans-serif; color: #1d2330; }
  #panel { position: absolute; left: 0; top: 0; bottom: 0; width: 410px; overflow-y: auto; box-sizing: border-box;
           padding: 10px 12px; background: #f4f6f9; border-right: 1px solid #c9ced8; }
  #meshcat-pane { position: absolute; left: 410px; top: 0; width: calc(100vw - 410px); height: 100vh; overflow: hidden; }
  h1 { font-size: 15px; margin: 0 0 4px; }
  .sub { color: #4a5365; margin-bottom: 6px; }
  #caption { font-size: 14px; font-weight: 600; background: #fff; border: 1px solid #c9ced8; border-radius: 4px;
             padding: 6px 8px; margin: 6px 0; min-height: 38px; }
  #controls { display: flex; gap: 4px; align-items: center; margin: 4px 0; }
  #controls button { font-size: 14px; min-width: 34px; padding: 2px 6px; cursor: pointer; }
  #scrub { width: 100%; margin: 4px 0 2px; }
  .row { display: flex; gap: 10px; flex-wrap: wrap; align-items: center; margin: 3px 0; color: #333; }
  .chip { display: inline-block; padding: 0 5px; border-radius: 3px; color: #fff; font-weight: 600; font-size: 12px; }
  ol#regrasp-timeline { list-style: none; padding: 0; margin: 6px 0; }
  ol#regrasp-timeline li { padding: 3px 6px; border-left: 4px solid transparent; cursor: pointer; }
  li.state { background: #fff; border: 1px solid #dde1e8; border-radius: 3px; margin: 2px 0; }
  li.step { color: #4a5365; font-size: 12px; padding-left: 18px !important; }
  li.current { border-left-color: #e6007e !important; background: #ffe9f4 !important; }
  .fc-yes { color: #137a2a; font-weight: 600; } .fc-no { color: #b3261e; font-weight: 600; }
  .sim { color: #005f7a; font-size: 12px; }
  .warn { color: #b3261e; }
  .legend span { margin-right: 8px; }
</style>
</head>
<body>
<div id="panel">
  <h1 id="title"></h1>
  <div class="sub" id="subtitle"></div>
  <div id="caption"></div>
  <div id="controls">
    <button id="btn-first" title="first state">|&#x25C0;</button>
    <button id="btn-prev" title="previous state">&#x25C0;&#x25C0;</button>
    <button id="btn-play" title="play / pause">&#x25B6;</button>
    <button id="btn-next" title="next state">&#x25B6;&#x25B6;</button>
    <button id="btn-last" title="last state">&#x25B6;|</button>
    <select id="speed" title="speed"><option value="0.5">0.5x</option><option value="1" selected>1x</option>
      <option value="2">2x</option></select>
  </div>
  <input type="range" id="scrub" min="0" max="0" value="0">
  <div class="row">
    <label><input type="checkbox" id="show-contacts" checked> contacts</label>
    <label><input type="checkbox" id="show-cones" checked> friction cones</label>
    <label id="sim-box" style="display:none"><input type="checkbox" id="show-sim" checked> simulator
      <select id="sim-run"></select></label>
    <button id="btn-sim" style="display:none" title="play what the simulator did: hand and object as pybullet moved them">&#x25B6; simulation</button>
  </div>
  <div class="row legend" id="legend"></div>
  <div id="run-verdict" class="sim"></div>
  <ol id="regrasp-timeline"></ol>
  <div class="sub">Drag to orbit, scroll to zoom, right-drag to pan. Contacts are in the object frame;
    cones open out of the object with half-angle atan(&mu;).</div>
</div>
<div id="meshcat-pane"></div>
<script>
/*MESHCAT_JS*/
</script>
<script>
"use strict";
const DATA = /*DATA*/;
const CMDS = /*COMMANDS*/;
const viewer = new MeshCat.Viewer(document.getElementById("meshcat-pane"));
for (const b64 of CMDS) {
  const s = atob(b64), a = new Uint8Array(s.length);
  for (let i = 0; i < s.length; i++) a[i] = s.charCodeAt(i);
  viewer.handle_command_bytearray(a);
}
const F = DATA.frames_per_step, NS = DATA.states.length, NK = DATA.steps.length;
const G = Math.max(1, NK * F);
const pathOf = p => ["meshcat"].concat(p.split("/").filter(x => x.length));
const node = p => viewer.scene_tree.find(pathOf(p));
const geomPaths = DATA.geoms.map(pathOf);
const hex = s => parseInt(s.slice(1), 16);
function materials(g) {
  const o = viewer.scene_tree.find(geomPaths[g].concat(["<object>"])).object;
  if (!o || !o.material) return [];
  return Array.isArray(o.material) ? o.material : [o.material];
}
function setColor(g, c) { for (const m of materials(g)) { if (m.color) m.color.setHex(c); if (m.emissive) m.emissive.setHex(c === hex(DATA.hand_color) ? 0 : 0x330018); } }
function setVisible(p, v) { const n = node(p); if (n && n.object) n.object.visible = v; }
function fmt(x, d) { return x === null || x === undefined ? "-" : Number(x).toPrecision(d || 3); }
function chip(f, label) { const c = DATA.colors[f] || "#555"; return `<span class="chip" style="background:${c}">${label || f}</span>`; }
function esc(t) { return String(t).replace(/&/g, "&amp;").replace(/</g, "&lt;").replace(/>/g, "&gt;"); }
function fcText(fc) { return fc ? '<span class="fc-yes">force closure</span>' : '<span class="fc-no">no closure</span>'; }

// ---- panel
document.getElementById("title").textContent = DATA.title;
const sm = DATA.summary;
document.getElementById("subtitle").innerHTML = `${DATA.hand} hand, ${DATA.object}, &mu; ${fmt(DATA.mu)}`
  + (DATA.kind === "plan" ? `<br>${NS} states, ${NK} steps` + (sm.gait_steps !== undefined ? `, ${sm.gait_steps} gait steps` : "")
     + (sm.bottleneck_metric !== undefined ? `, bottleneck metric ${fmt(sm.bottleneck_metric)}` : "")
     + (sm.bottleneck_grip_force_n ? `, largest grip ${fmt(sm.bottleneck_grip_force_n)} N` : "")
     + (DATA.contact_model ? `, contact model ${DATA.contact_model}` : "") : "<br>one grasp (what regrasp check finds)");
document.getElementById("legend").innerHTML = DATA.fingers.map(f => chip(f)).join(" ")
  + ` <span class="chip" style="background:${DATA.moving_color}">moving finger</span>`
  + (DATA.runs.length ? ` <span class="chip" style="background:${DATA.sim_color}">simulator contacts</span>` : "")
  + `<br><span class="scale">grid: 1 cm cells in the palm plane; axes 5 cm: x red, y green, z blue (palm frame)</span>`;
const simSel = document.getElementById("sim-run");
if (DATA.runs.length) {
  document.getElementById("sim-box").style.display = "";
  DATA.runs.forEach((r, i) => { const o = document.createElement("option"); o.value = i; o.textContent = r.name; simSel.appendChild(o); });
}
const tl = document.getElementById("regrasp-timeline");
tl.dataset.states = NS; tl.dataset.steps = NK;
function stateHTML(i) {
  const s = DATA.states[i];
  let h = `<b>state ${i}</b> ${fcText(s.force_closure)}, metric ${fmt(s.metric)}`
    + (s.grip_force_n !== null ? `, grip ${fmt(s.grip_force_n)} N` : "")
    + `<br>contacts ${s.contacts.map(f => chip(f)).join(" ") || "-"}; removable: ${s.removable.join(", ") || "-"}`;
  if (s.mean_contact) h += `<br>one mean contact per finger: ${fcText(s.mean_contact.force_closure)}, metric ${fmt(s.mean_contact.metric)}`;
  if (s.problems && s.problems.length) h += `<br><span class="fc-no">fails regrasp check:</span><ul class="warn">`
    + s.problems.map(p => `<li>${esc(p)}</li>`).join("") + "</ul>";
  if (s.missing && s.missing.length) h += `<br><span class="warn">not touching: ${s.missing.join(", ")}</span>`;
  if (s.collisions && s.collisions.length) h += `<br><span class="warn">collisions: ${s.collisions.join("; ")}</span>`;
  h += `<div class="sim" data-sim="${i}"></div>`;
  return h;
}
for (let i = 0; i < NS; i++) {
  const li = document.createElement("li"); li.className = "state"; li.dataset.state = i; li.innerHTML = stateHTML(i);
  li.onclick = () => { pause(); seek(statePos(i)); }; tl.appendChild(li);
  const k = DATA.steps.findIndex(s => s.from === i);
  if (k >= 0) {
    const st = DATA.steps[k], st_li = document.createElement("li");
    st_li.className = "step"; st_li.dataset.step = k;
    st_li.innerHTML = `&darr; step ${k + 1}: ${chip(st.finger)} ${st.action} (state ${st.from} &rarr; ${st.to})`;
    st_li.onclick = () => { pause(); seek(k * F + Math.floor(F / 2)); }; tl.appendChild(st_li);
  }
}
function fillSim() {
  const r = DATA.runs[+simSel.value || 0];
  document.getElementById("run-verdict").textContent = r ? `replay ${r.name}: ${r.verdict}` : "";
  for (const d of document.querySelectorAll("[data-sim]")) {
    if (!r) { d.innerHTML = ""; continue; }
    const s = r.states[+d.dataset.sim];
    d.innerHTML = !s.reached ? "simulator: not reached" :
      `simulator: ${fcText(s.force_closure)}, metric ${fmt(s.metric)}, touching ${s.fingers.join(", ") || "-"}, `
      + `drift ${fmt(s.drift_mm, 2)} mm / ${fmt(s.drift_deg, 2)} deg`;
  }
}

// ---- scene state
let pos = 0, cur = { state: -1, step: -2 }, playing = null, hold = 0;
const allSets = new Set();
DATA.states.forEach(s => s.sets.forEach(n => allSets.add(n)));
DATA.runs.forEach(r => r.states.forEach(s => s.sets.forEach(n => allSets.add(n))));
function where(g) {
  if (NK === 0) return { step: -1, frame: 0, state: 0 };
  const k = Math.min(NK - 1, Math.floor(g / F)), j = g - k * F, st = DATA.steps[k];
  return { step: k, frame: j, state: j < F / 2 ? st.from : st.to };
}
function statePos(i) {
  const k = DATA.steps.findIndex(s => s.from === i);
  if (k >= 0) return k * F;
  const kk = DATA.steps.findIndex(s => s.to === i);
  return kk >= 0 ? kk * F + F - 1 : 0;
}
function showContacts(state) {
  const showC = document.getElementById("show-contacts").checked, showK = document.getElementById("show-cones").checked;
  const showS = document.getElementById("show-sim").checked;
  const on = new Set(showC ? DATA.states[state].sets : []);
  const r = DATA.runs[+simSel.value || 0];
  if (r && showS) r.states[state].sets.forEach(n => on.add(n));
  for (const n of allSets) {
    setVisible("regrasp/object/contacts/" + n, on.has(n));
    if (n.startsWith("plan")) setVisible("regrasp/object/contacts/" + n + "/cones", showK);
  }
}
function seek(g) {
  pos = Math.max(0, Math.min(G - 1, g));
  const w = where(pos);
  const base = DATA.states[w.step >= 0 ? DATA.steps[w.step].from : 0].T;
  const frame = w.step >= 0 ? DATA.steps[w.step].frames[w.frame] : {};
  for (let i = 0; i < base.length; i++) viewer.set_transform(geomPaths[i], frame[i] || base[i]);
  // the object at the state's pose, or along a reposing step's object path (schema 4)
  const sk = w.step >= 0 ? DATA.steps[w.step] : null;
  const objT = sk && sk.obj ? sk.obj[w.frame] : DATA.states[sk ? sk.from : 0].obj;
  if (objT) viewer.set_transform(objPath, objT);
  if (w.step !== cur.step) {
    const moving = w.step >= 0 ? DATA.steps[w.step].finger : null;
    DATA.geom_finger.forEach((f, i) => setColor(i, f !== null && f === moving ? hex(DATA.moving_color) : hex(DATA.hand_color)));
  }
  showContacts(w.state);
  cur = w;
  document.getElementById("scrub").value = pos;
  for (const li of tl.children) {
    const isCur = (li.dataset.state !== undefined && +li.dataset.state === w.state && (w.step < 0 || w.frame === 0 || w.frame === F - 1))
      || (li.dataset.step !== undefined && +li.dataset.step === w.step && w.frame > 0 && w.frame < F - 1);
    li.classList.toggle("current", isCur);
    if (isCur && li.scrollIntoView) li.scrollIntoView({block: "nearest"});  // the list follows the timeline
  }
  const s = DATA.states[w.state];
  let cap = "";
  if (w.step >= 0) {
    const st = DATA.steps[w.step];
    cap = `Step ${w.step + 1}/${NK}: ${chip(st.finger)} <span style="color:${DATA.moving_color}">${st.action}</span> `
      + `(state ${st.from} &rarr; ${st.to})<br>`;
  }
  if (s.problems && s.problems.length) cap += `<span class="fc-no">FAILS regrasp check (${s.problems.length} problem`
    + `${s.problems.length > 1 ? "s" : ""}: see the list)</span><br>`;
  cap += `state ${w.state}: ${fcText(s.force_closure)}, metric ${fmt(s.metric)}, removable: ${s.removable.join(", ") || "-"}`;
  const r = DATA.runs[+simSel.value || 0];
  if (r && r.states[w.state].reached) cap += `<br><span class="sim">simulator (${r.name}): drift ${fmt(r.states[w.state].drift_mm, 2)} mm, `
    + `${r.states[w.state].force_closure ? "force closure" : "no closure"}</span>`;
  document.getElementById("caption").innerHTML = cap;
  viewer.set_dirty();
}
function tick() {
  if (hold > 0) { hold--; return; }
  if (pos >= G - 1) { pause(); return; }
  seek(pos + 1);
  if (cur.frame === F - 1) hold = 6;
}
function play() {
  if (NK === 0) return;
  if (pos >= G - 1) seek(0);
  pause();
  playing = setInterval(tick, 80 / +document.getElementById("speed").value);
  document.getElementById("btn-play").innerHTML = "||";
}
function pause() {
  if (playing) clearInterval(playing);
  playing = null;
  document.getElementById("btn-play").innerHTML = "&#x25B6;";
}
document.getElementById("btn-play").onclick = () => (playing ? pause() : play());
document.getElementById("btn-first").onclick = () => { pause(); seek(0); };
document.getElementById("btn-last").onclick = () => { pause(); seek(G - 1); };
document.getElementById("btn-next").onclick = () => { pause(); seek(statePos(Math.min(NS - 1, cur.state + 1))); };
document.getElementById("btn-prev").onclick = () => { pause(); seek(statePos(Math.max(0, cur.state - (cur.frame === 0 || cur.frame === F - 1 || cur.step < 0 ? 1 : 0)))); };
document.getElementById("speed").onchange = () => { if (playing) play(); };
const scrub = document.getElementById("scrub");
scrub.max = G - 1; scrub.disabled = NK === 0;
scrub.oninput = () => { pause(); seek(+scrub.value); };
for (const id of ["show-contacts", "show-cones", "show-sim"]) document.getElementById(id).onchange = () => seek(pos);
simSel.onchange = () => { fillSim(); seek(pos); };
// the simulator's own motion (replay report trajectory): hand and object as pybullet moved
// them, a drop seen as a drop; the plan's state stays selected in the list
let simPlay = null;
const btnSim = document.getElementById("btn-sim");
const objPath = pathOf("regrasp/object");
function plainHand() {  // no finger is "the moving one" in the simulator's motion
  DATA.geom_finger.forEach((f, i) => setColor(i, hex(DATA.hand_color)));
  cur = Object.assign({}, cur, { step: -2 });  // the plan's colours come back at the next seek
}
function simRun() { const r = DATA.runs[+simSel.value || 0]; return r && r.traj ? r : null; }
function stopSim() {
  if (simPlay) clearInterval(simPlay);
  simPlay = null;
  btnSim.innerHTML = "&#x25B6; simulation";
  const r = simRun();
  if (r) viewer.set_transform(objPath, r.traj.object_plan);
  seek(pos);
}
function playSim() {
  const r = simRun();
  if (!r) return;
  pause();
  const fr = r.traj.frames, base = DATA.states[0].T;
  let k = 0;
  plainHand();
  for (let i = 0; i < base.length; i++) viewer.set_transform(geomPaths[i], base[i]);
  btnSim.innerHTML = "&#x25A0; simulation";
  simPlay = setInterval(() => {
    if (k >= fr.length) { clearInterval(simPlay); simPlay = null; btnSim.innerHTML = "&#x25B6; simulation"; return; }
    const f = fr[k++];
    for (const g in f.hand) viewer.set_transform(geomPaths[+g], f.hand[g]);
    viewer.set_transform(objPath, f.obj);
    document.getElementById("caption").innerHTML = `<span class="sim">simulator (${esc(r.name)}): t ${fmt(f.t, 3)} s `
      + `of ${fmt(fr[fr.length - 1].t, 3)} s; ${esc(r.verdict).slice(0, 160)}</span>`;
    document.body.dataset.simFrame = k;
    viewer.set_dirty();
  }, 1000 * (fr.length > 1 ? fr[1].t - fr[0].t : 0.033) / +document.getElementById("speed").value);
}
btnSim.onclick = () => (simPlay ? stopSim() : playSim());
function showSimButton() { btnSim.style.display = simRun() ? "" : "none"; }
showSimButton();
simSel.addEventListener("change", () => { if (simPlay) stopSim(); showSimButton(); });
document.addEventListener("keydown", e => {
  if (e.key === " ") { e.preventDefault(); playing ? pause() : play(); }
  else if (e.key === "ArrowRight") { pause(); seek(pos + 1); }
  else if (e.key === "ArrowLeft") { pause(); seek(pos - 1); }
});
for (const b of ["btn-first", "btn-prev", "btn-play", "btn-next", "btn-last"]) document.getElementById(b).disabled = NK === 0;

// ---- camera: looks at the contacts from the grasping side of the palm (page z = palm normal)
(function () {
  const e = DATA.camera.eye, t = DATA.camera.target, cam = viewer.camera;
  cam.near = 0.002; cam.far = 20; cam.fov = 40;
  cam.position.set(e[0], e[2], -e[1]);          // meshcat's camera lives in a y-up frame
  viewer.controls.target.set(t[0], t[2], -t[1]);
  cam.updateProjectionMatrix(); viewer.controls.update();
})();
// meshcat's gradient background is an RGB DataTexture that WebGL2 (e.g. software GL) may draw black
viewer.scene.background = new MeshCat.THREE.Color(DATA.background);
// a hand-sized grid in the palm plane (1 cm cells, 30 cm across) and 5 cm palm-frame axes
// (x red, y green, z blue) instead of meshcat's 20 m grid: the scale of the scene at a glance
(function () {
  const grid = new MeshCat.THREE.GridHelper(0.3, 30, 0x8a93a3, 0xd2d7e0);
  grid.rotateX(Math.PI / 2);
  viewer.set_object(["regrasp", "scale", "grid"], grid);   // "regrasp" holds the palm frame
  viewer.set_object(["regrasp", "scale", "axes"], new MeshCat.THREE.AxesHelper(0.05));
})();
fillSim();
const start = /frame=(\d+)/.exec(location.hash);   // page.html#frame=40 opens at frame 40
seek(start ? +start[1] : 0);
const simAt = /sim=(\d+)/.exec(location.hash);   // page.html#sim=60: the simulator at its frame 60 (screenshots)
if (simAt && simRun()) {
  const r = simRun(), fr = r.traj.frames, n = Math.min(fr.length, +simAt[1] + 1);
  plainHand();
  for (let k = 0; k < n; k++) { for (const g in fr[k].hand) viewer.set_transform(geomPaths[+g], fr[k].hand[g]); }
  viewer.set_transform(objPath, fr[n - 1].obj);
  document.getElementById("caption").innerHTML = `<span class="sim">simulator (${esc(r.name)}): t ${fmt(fr[n - 1].t, 3)} s; `
    + `${esc(r.verdict).slice(0, 160)}</span>`;
  viewer.set_dirty();
}
document.body.dataset.ready = "1";
document.body.dataset.readyMs = Math.round(performance.now());
requestAnimationFrame(() => requestAnimationFrame(() => { document.body.dataset.firstFrameMs = Math.round(performance.now()); }));
</script>
</body>
</html>
"""
