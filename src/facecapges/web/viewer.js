// FaceCapGes live viewer (ES module, three.js 0.187.0; @pixiv/three-vrm 3.5.5 for a VRM).
//
// The avatar is plugged in: a server that shows a VRM (`live --web --avatar FILE.vrm`) serves the VRM's
// frame layout at /vrm/layout.json and the viewer draws it with VrmScene (vrm_scene.js); otherwise our
// avatar /avatar.glb with AvatarScene (avatar_scene.js). Both implement the avatar-scene interface
// (avatar_scene.js), so the rest of this page is one: connects to ws://<this host>/ws and draws the newest
// feed message of the avatar's kind on every animation frame — for our avatar a `pose` message
// (facecapges/runtime/outputs/protocol.py: local joint quaternions (w, x, y, z) of the 47 upper-body BEAT
// joints and 52 ARKit weights, in the names of the `hello` message; joints the feed does not name stay at
// rest), for a VRM a `vrm_pose` message (already retargeted by the server:
// facecapges/runtime/outputs/vrm_viewer.py). Shows frame rate, compute and transport latency; checkboxes
// toggle a skeleton overlay and the face close-up. Several faces (`live --faces N`, our avatar): the `face`
// field of a message picks the avatar; avatar i is a copy of the first, placed left to right.
// State for tests: window.facecapgesViewer.
import * as THREE from 'three';
import { VIEWS } from './avatar_scene.js';
import { intensitySlider } from './intensity.js';

const slider = intensitySlider();

const $ = (id) => document.getElementById(id);
const state = {
  ready: false, connected: false, hello: null, frames: 0, drawn: 0, lastFrame: -1, faceFound: null, avatars: 1,
  fpsIn: 0, fpsDrawn: 0, computeMs: null, transportMs: null, errors: [],
};
window.facecapgesViewer = state;
window.addEventListener('error', (e) => state.errors.push(String(e.message || e)));

let scene = null;
let pending = null;  // newest unseen feed message (the first face's)
const others = new Map();  // face index > 0 -> newest unseen feed message
const copies = [];   // avatars of faces 1, 2, … (scene.copy())
const recentCompute = [];
const arrivals = [];
const draws = [];
let helper = null;

// the avatar's scene module: a VRM when the server holds a VRM layout
async function openScene() {
  const res = await fetch('/vrm/layout.json');
  const layout = res.ok ? await res.json() : null;  // null from our glTF avatar's server
  const { default: Scene } = await (layout ? import('./vrm_scene.js') : import('./avatar_scene.js'));
  // (the face close-up inset in the corner: on our avatar, as ever; a VRM has the face close-up checkbox)
  scene = new Scene($('c'), { width: innerWidth, height: innerHeight, inset: !layout });
  const problems = await scene.open(layout);
  state.errors.push(...problems);
}

function resize() {
  if (!scene) return;
  scene.renderer.setSize(innerWidth, innerHeight, false);
  scene.camera.aspect = innerWidth / innerHeight;
  scene.camera.updateProjectionMatrix();
}
addEventListener('resize', resize);

function place() {
  const n = 1 + copies.length, gap = 1.1;
  [scene.root, ...copies.map((c) => c.root)].forEach((r, i) => { r.position.x = (i - (n - 1) / 2) * gap; });
  const v = VIEWS.body;
  scene.setView({ ...v, distance: v.distance * Math.max(1, 0.45 + 0.55 * n) });
  state.avatars = n;
}

function copyFor(face) {
  while (copies.length < face) {
    const c = scene.copy();
    if (!c) return null;
    copies.push(c);
    place();
  }
  return copies[face - 1];
}

function draw(target, msg) {
  target.setPose(msg.pose);
  target.setFace(msg.weights);
}

function rate(list, now) {
  while (list.length && now - list[0] > 1000) list.shift();
  return list.length;
}

function onMessage(msg) {
  if (msg.type === 'hello') { state.hello = msg; if (state.ready) scene.useHello(msg); return; }
  if (!scene || msg.type !== scene.feedMessage) return;
  if (msg.face) { others.set(msg.face, msg); return; }
  const now = performance.now();
  state.frames += 1;
  arrivals.push(now);
  if (msg.sent_ms !== undefined) state.transportMs = Math.max(0, Date.now() - msg.sent_ms);
  if (msg.latency_ms && msg.latency_ms.total !== undefined) {
    recentCompute.push(msg.latency_ms.total);
    if (recentCompute.length > 30) recentCompute.shift();
  }
  pending = msg;
}

function connect() {
  const ws = new WebSocket(`ws://${location.host}/ws`);
  slider.attach(ws);
  ws.onopen = () => { state.connected = true; $('status').textContent = 'connected'; $('status').className = 'ok'; };
  ws.onclose = () => {
    state.connected = false; $('status').textContent = 'disconnected (retrying)'; $('status').className = 'bad';
    setTimeout(connect, 1000);
  };
  ws.onmessage = (ev) => {
    const msg = JSON.parse(ev.data);
    if (!slider.handle(msg)) onMessage(msg);
  };
}

function hud(now) {
  state.fpsIn = rate(arrivals, now);
  state.fpsDrawn = rate(draws, now);
  if (recentCompute.length) {
    const s = [...recentCompute].sort((a, b) => a - b);
    state.computeMs = s[Math.floor(s.length / 2)];
  }
  $('frame').textContent = state.lastFrame >= 0 ? String(state.lastFrame) : '–';
  $('fps').textContent = String(state.fpsIn);
  $('rfps').textContent = String(state.fpsDrawn);
  $('lat').textContent = state.computeMs === null ? '–' : state.computeMs.toFixed(1);
  $('net').textContent = state.transportMs === null ? '–' : state.transportMs.toFixed(0);
  $('face').textContent = state.faceFound === null ? '–' : (state.faceFound ? 'tracked' : 'lost (holding/easing)');
}

function loop() {
  const now = performance.now();
  const live = state.ready && scene.feedReady;
  if (live && others.size) {
    others.forEach((msg, face) => { const c = copyFor(face); if (c) draw(c, msg); });
    others.clear();
    if (!pending) scene.render();
  }
  if (pending && live) {
    draw(scene, pending);
    state.lastFrame = pending.frame;
    state.faceFound = pending.face_found;
    pending = null;
    scene.render();
    state.drawn += 1;
    draws.push(now);
  }
  hud(now);
  requestAnimationFrame(loop);
}

$('skel').addEventListener('change', (e) => {
  if (!helper) return;
  helper.visible = e.target.checked;
  scene.render();
});
$('faceview').addEventListener('change', (e) => {
  if (!scene) return;
  scene.setView(e.target.checked ? 'face' : 'body');
  scene.render();
});

openScene().then(() => {
  helper = new THREE.SkeletonHelper(scene.root);
  helper.visible = false;
  scene.scene.add(helper);
  state.ready = true;
  const d = scene.describe();
  state.joints = d.joints;
  if (d.metaVersion !== undefined) Object.assign(state, { bones: d.joints, metaVersion: d.metaVersion });
  $('name').textContent = scene.label;
  if (state.hello) scene.useHello(state.hello);
  resize();
  scene.setView('body');
  scene.render();
}).catch((e) => state.errors.push(String(e)));

// for tests and scripts
state.setSkeleton = (on) => { $('skel').checked = on; $('skel').dispatchEvent(new Event('change')); return on; };
connect();
requestAnimationFrame(loop);
