// FaceCapGes live viewer for a VRM (ES module, three.js 0.187.0 + @pixiv/three-vrm 3.5.5).
//
// Loads /avatar.vrm and /vrm/layout.json ({"bones", "expressions"}), connects to ws://<host>/ws and draws
// the newest `vrm_pose` message (normalised bone quaternions (w, x, y, z) + expression weights, already
// retargeted by the server: facecapges/runtime/outputs/vrm_viewer.py) on every animation frame.
// State for tests: window.facecapgesViewer.
import { VrmScene } from './vrm_scene.js';
import { intensitySlider } from './intensity.js';

const slider = intensitySlider();

const $ = (id) => document.getElementById(id);
const scene = new VrmScene($('c'), { width: innerWidth, height: innerHeight });
const state = { ready: false, connected: false, frames: 0, drawn: 0, lastFrame: -1, errors: [], bones: 0 };
window.facecapgesViewer = state;
window.addEventListener('error', (e) => state.errors.push(String(e.message || e)));
let pending = null;
const arrivals = [];

function resize() {
  scene.renderer.setSize(innerWidth, innerHeight, false);
  scene.camera.aspect = innerWidth / innerHeight;
  scene.camera.updateProjectionMatrix();
}
addEventListener('resize', resize);

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
    if (slider.handle(msg)) return;
    if (msg.type !== 'vrm_pose') return;
    state.frames += 1;
    arrivals.push(performance.now());
    if (msg.latency_ms && msg.latency_ms.total !== undefined) $('lat').textContent = msg.latency_ms.total.toFixed(1);
    pending = msg;
  };
}

function loop() {
  const now = performance.now();
  while (arrivals.length && now - arrivals[0] > 1000) arrivals.shift();
  if (pending && state.ready) {
    scene.setPose(pending.pose);
    scene.setExpressions(pending.weights);
    scene.render();
    state.lastFrame = pending.frame;
    state.drawn += 1;
    pending = null;
  }
  $('frame').textContent = state.lastFrame >= 0 ? String(state.lastFrame) : '–';
  $('fps').textContent = String(arrivals.length);
  requestAnimationFrame(loop);
}

$('faceview').addEventListener('change', (e) => { scene.setView(e.target.checked ? 'face' : 'body'); scene.render(); });

(async () => {
  const layout = await (await fetch('/vrm/layout.json')).json();
  await scene.load('/avatar.vrm');
  resize();
  const missing = scene.setLayout(layout.bones, layout.expressions);
  if (missing.bones.length) state.errors.push(`no normalised bones ${missing.bones.join(', ')}`);
  state.bones = layout.bones.length;
  state.metaVersion = scene.metaVersion;
  $('name').textContent = (scene.vrm.meta.name || scene.vrm.meta.title || 'VRM') + ` (VRM ${scene.metaVersion})`;
  state.ready = true;
  scene.setView('body');
  scene.render();
})().catch((e) => state.errors.push(String(e)));

connect();
requestAnimationFrame(loop);
