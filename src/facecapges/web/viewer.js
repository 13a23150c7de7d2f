// FaceCapGes live viewer (ES module, three.js 0.187.0).
//
// Connects to ws://<this host>/ws, reads the `hello` message (joint and blendshape names) and then one
// `pose` message per frame (facecapges/runtime/outputs/protocol.py): local joint quaternions (w, x, y, z) of the
// 47 upper-body BEAT joints and 52 ARKit weights. Joints the feed does not name stay at rest. Draws the
// newest frame on every animation frame; shows frame rate, compute and transport latency; a checkbox
// toggles a skeleton overlay. Several faces (`live --faces N`): the `face` field of a pose message picks the
// avatar; avatar i is a clone of the first, placed left to right. State for tests: window.facecapgesViewer.
import * as THREE from 'three';
import * as SkeletonUtils from 'three/addons/utils/SkeletonUtils.js';
import { AvatarScene, VIEWS } from './avatar_scene.js';
import { intensitySlider } from './intensity.js';

const slider = intensitySlider();

const $ = (id) => document.getElementById(id);
const canvas = $('c');
const scene = new AvatarScene(canvas, { width: innerWidth, height: innerHeight, inset: true });
const state = {
  ready: false, connected: false, hello: null, frames: 0, drawn: 0, lastFrame: -1, faceFound: null, avatars: 1,
  fpsIn: 0, fpsDrawn: 0, computeMs: null, transportMs: null, errors: [],
};
window.facecapgesViewer = state;
window.addEventListener('error', (e) => state.errors.push(String(e.message || e)));

let jointMap = [];   // feed joint k -> scene joint object
let blendMap = [];   // feed blendshape k -> index in scene.blendshapeNames
let pending = null;  // newest unseen pose message (the first face's)
const others = new Map();  // face index > 0 -> newest unseen pose message
const clones = [];   // avatars of faces 1, 2, …: {root, joints: feed k -> bone, morphs: [[mesh, idx]]}
const recentCompute = [];
const arrivals = [];
const draws = [];
let helper = null;

function resize() {
  scene.renderer.setSize(innerWidth, innerHeight, false);
  scene.camera.aspect = innerWidth / innerHeight;
  scene.camera.updateProjectionMatrix();
}
addEventListener('resize', resize);

function buildMaps() {
  const byName = new Map(scene.jointNames.map((n, i) => [n, scene.joints[i]]));
  jointMap = state.hello.joints.map((n) => byName.get(n) || null);
  const bIdx = new Map(scene.blendshapeNames.map((n, i) => [n, i]));
  blendMap = state.hello.blendshapes.map((n) => bIdx.has(n) ? bIdx.get(n) : -1);
}

function place() {
  const n = 1 + clones.length, gap = 1.1;
  [scene.root, ...clones.map((c) => c.root)].forEach((r, i) => { r.position.x = (i - (n - 1) / 2) * gap; });
  const v = VIEWS.body;
  scene.setView({ ...v, distance: v.distance * Math.max(1, 0.45 + 0.55 * n) });
  state.avatars = n;
}

function cloneFor(face) {
  while (clones.length < face) {
    const root = SkeletonUtils.clone(scene.root);
    scene.scene.add(root);
    const byName = new Map();
    root.traverse((o) => { if (!byName.has(o.name)) byName.set(o.name, o); });
    const morphs = [];
    root.traverse((o) => {
      if (o.isMesh && o.morphTargetDictionary) morphs.push([o, scene.blendshapeNames.map((n) => o.morphTargetDictionary[n])]);
    });
    clones.push({ root, joints: state.hello.joints.map((n) => byName.get(n) || null), morphs });
    place();
  }
  return clones[face - 1];
}

function applyClone(c, msg) {
  const q = msg.pose;
  c.joints.forEach((j, k) => { if (j) j.quaternion.set(q[4 * k + 1], q[4 * k + 2], q[4 * k + 3], q[4 * k]); });
  c.morphs.forEach(([m, idx]) => {
    msg.weights.forEach((v, k) => { const b = blendMap[k]; if (b >= 0 && idx[b] !== undefined) m.morphTargetInfluences[idx[b]] = v; });
  });
}

function apply(msg) {
  const q = msg.pose;
  for (let k = 0; k < jointMap.length; k++) {
    const j = jointMap[k];
    if (j) j.quaternion.set(q[4 * k + 1], q[4 * k + 2], q[4 * k + 3], q[4 * k]);
  }
  const w = new Array(scene.blendshapeNames.length).fill(0);
  msg.weights.forEach((v, k) => { if (blendMap[k] >= 0) w[blendMap[k]] = v; });
  scene.setBlendshapes(w);
}

function rate(list, now) {
  while (list.length && now - list[0] > 1000) list.shift();
  return list.length;
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
    if (slider.handle(msg)) return;
    if (msg.type === 'hello') { state.hello = msg; if (state.ready) buildMaps(); return; }
    if (msg.type !== 'pose') return;
    if (msg.face) { others.set(msg.face, msg); return; }
    const now = performance.now();
    state.frames += 1;
    arrivals.push(now);
    state.transportMs = Math.max(0, Date.now() - msg.sent_ms);
    if (msg.latency_ms && msg.latency_ms.total !== undefined) {
      recentCompute.push(msg.latency_ms.total);
      if (recentCompute.length > 30) recentCompute.shift();
    }
    pending = msg;
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
  if (state.ready && state.hello && others.size) {
    others.forEach((msg, face) => applyClone(cloneFor(face), msg));
    others.clear();
    if (!pending) scene.render();
  }
  if (pending && state.ready && state.hello) {
    apply(pending);
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
$('faceview').addEventListener('change', (e) => { scene.setView(e.target.checked ? 'face' : 'body'); scene.render(); });

scene.load('/avatar.glb').then(() => {
  helper = new THREE.SkeletonHelper(scene.root);
  helper.visible = false;
  scene.scene.add(helper);
  state.ready = true;
  state.joints = scene.jointNames.length;
  if (state.hello) buildMaps();
  resize();
  scene.render();
}).catch((e) => state.errors.push(String(e)));

// for tests and scripts
state.setSkeleton = (on) => { $('skel').checked = on; $('skel').dispatchEvent(new Event('change')); return on; };
connect();
requestAnimationFrame(loop);
