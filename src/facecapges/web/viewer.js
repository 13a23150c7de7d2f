// FaceCapGes live viewer (ES module, three.js 0.187.0; @pixiv/three-vrm 3.5.5 for a VRM).
//
// The avatar is plugged in: a server that shows a VRM (`live --web --avatar FILE.vrm`) serves the VRM's
// frame layout at /vrm/layout.json and the viewer draws it with VrmScene (vrm_scene.js); otherwise our
// avatar /avatar.glb with AvatarScene (avatar_scene.js). Both implement the avatar-scene interface
// (avatar_scene.js), so the rest of this page is one: connects to ws://<this host>/ws and draws the newest
// feed message of the avatar's kind on every animation frame — for our avatar a `pose` message
// (facecapges.runtime.outputs.protocol: local joint quaternions (w, x, y, z) of the 47 upper-body BEAT
// joints and 52 ARKit weights, in the names of the `hello` message; joints the feed does not name stay at
// rest), for a VRM a `vrm_pose` message (already retargeted by the server:
// facecapges.runtime.outputs.vrm_viewer). Shows frame rate, compute and transport latency; checkboxes
// toggle a skeleton overlay and the face close-up. Several faces (`live --faces N`, our avatar): the `face`
// field of a message picks the avatar; avatar i is a copy of the first, placed left to right.
// Between the model's frames (`live --rate R`): the server then says so once (`{"type": "rate", "fps": 15,
// "rate": 30}`, facecapges.runtime.outputs.viewer) and sends the model's frames only; the page blends
// towards each one as the upsampler of the VMC stream does (facecapges.runtime.outputs.upsample: from what
// is on screen when it comes, weight min(1, elapsed/period + fps/rate), quaternions by slerp, weights
// linearly): the same added latency, drawn at the display's rate instead of R.
// The mouse moves the camera (three's OrbitControls): drag to orbit, wheel to zoom, right-drag to pan.
//
// URL parameters, for OBS's browser source and other embeds (README, "OBS browser source"):
//   bg=transparent | RRGGBB   no background (alpha 0 wherever the avatar is not) or a colour (default eef0f3)
//   hud=0                     no HUD panel and no face close-up inset: the avatar alone
//   frame=head|upper|full     the camera on the avatar's head and shoulders, its upper body to the hips, or all
//                             of it (default: the viewer's body view)
//   orbit=0                   the mouse does not move the camera
// A value it does not know is reported in the HUD and in state.errors, and the default is used.
// State for tests: window.facecapgesViewer.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { FRAMES } from './avatar_scene.js';
import { intensitySlider } from './intensity.js';

const slider = intensitySlider();

const $ = (id) => document.getElementById(id);
const state = {
  ready: false, connected: false, hello: null, frames: 0, drawn: 0, lastFrame: -1, faceFound: null, avatars: 1,
  fpsIn: 0, fpsDrawn: 0, computeMs: null, transportMs: null, errors: [], rate: null, blends: 0,
};
window.facecapgesViewer = state;
window.addEventListener('error', (e) => state.errors.push(String(e.message || e)));

// the URL's parameters (see above) -> {background: colour or null (transparent), hud, frame, orbit}
function pageOptions(search) {
  const q = new URLSearchParams(search), opts = { background: 0xeef0f3, hud: true, frame: 'body', orbit: true };
  const bad = (name, allowed) => state.errors.push(`URL parameter ${name}=${q.get(name)}: expected ${allowed}`);
  const flag = (name) => {
    if (!q.has(name)) return true;
    if (q.get(name) === '0' || q.get(name) === '1') return q.get(name) === '1';
    bad(name, '0 or 1');
    return true;
  };
  if (q.has('bg')) {
    const bg = q.get('bg').replace(/^#/, '');
    if (bg === 'transparent') opts.background = null;
    else if (/^[0-9a-f]{6}$/i.test(bg)) opts.background = parseInt(bg, 16);
    else bad('bg', 'transparent or a colour RRGGBB');
  }
  if (q.has('frame')) {
    if (FRAMES.includes(q.get('frame'))) opts.frame = q.get('frame');
    else bad('frame', FRAMES.join(', '));
  }
  opts.hud = flag('hud');
  opts.orbit = flag('orbit');
  return opts;
}
const options = pageOptions(location.search);
state.options = options;
if (options.background === null) for (const e of [document.documentElement, document.body]) e.style.background = 'transparent';
else document.body.style.background = '#' + options.background.toString(16).padStart(6, '0');
if (!options.hud) $('hud').style.display = 'none';

let scene = null;
let pending = null;  // newest unseen feed message (the first face's)
const others = new Map();  // face index > 0 -> newest unseen feed message
const copies = [];   // avatars of faces 1, 2, … (scene.copy())
const recentCompute = [];
const arrivals = [];
const draws = [];
let helper = null;
let controls = null;
let view = options.frame;  // the view shown: options.frame, 'face' (the close-up checkbox) or a view object
let steps = 1;       // rate / fps of the server's `rate` message: 1 = each frame drawn as it comes
let periodMs = 0;    // the model's frame period (1000 / fps)
let shown = null;    // {pose, weights} on screen (the first face)
let blend = null;    // {from, to: a feed message, t0: its arrival (ms)}: the blend on screen (see the top)

// the avatar's scene module: a VRM when the server holds a VRM layout
async function openScene() {
  const res = await fetch('/vrm/layout.json');
  const layout = res.ok ? await res.json() : null;  // null from our glTF avatar's server
  const { default: Scene } = await (layout ? import('./vrm_scene.js') : import('./avatar_scene.js'));
  // (the face close-up inset in the corner: on our avatar with the HUD, as ever; a VRM has the face close-up
  // checkbox)
  scene = new Scene($('c'), { width: innerWidth, height: innerHeight, inset: !layout && options.hud,
                              background: options.background });
  const problems = await scene.open(layout);
  state.errors.push(...problems);
}

// show view `v` (a name or a view object): the camera and the mouse's orbit centre
function look(v) {
  view = v;
  scene.setView(v);
  if (controls) { controls.target.copy(scene.target); controls.update(); }
  scene.render();
}

// (a new size frames the view again: what the mouse moved is reset)
function resize() {
  if (!scene) return;
  scene.renderer.setSize(innerWidth, innerHeight, false);
  scene.camera.aspect = innerWidth / innerHeight;
  scene.camera.updateProjectionMatrix();
  if (state.ready) (copies.length ? place() : look(view));
}
addEventListener('resize', resize);

function place() {
  const n = 1 + copies.length, gap = 1.1;
  [scene.root, ...copies.map((c) => c.root)].forEach((r, i) => { r.position.x = (i - (n - 1) / 2) * gap; });
  const v = scene.view(options.frame);
  look({ ...v, distance: v.distance * Math.max(1, 0.45 + 0.55 * n) });
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

// `w` of the way from frame `a` to frame `b` ({pose: flat (w, x, y, z) quaternions, weights}): each quaternion
// by three's slerp the short way round (its formula is the same in any order of the four components; under
// 3.6° a lerp, normalised: the same to ~1e-5 rad), the weights linearly
function between(a, b, w) {
  const p = new Float64Array(b.pose.length), f = new Float64Array(b.weights.length);
  for (let i = 0; i < p.length; i += 4) THREE.Quaternion.slerpFlat(p, i, a.pose, i, b.pose, i, w);
  for (let i = 0; i < f.length; i++) f[i] = (1 - w) * a.weights[i] + w * b.weights[i];
  return { pose: p, weights: f };
}

// what to draw now (null: nothing new): the newest frame, or with `steps` > 1 the blend towards it
function frameNow(now) {
  if (!blend) return null;
  const w = blend.from ? Math.min(1, (now - blend.t0) / periodMs + 1 / steps) : 1;
  const fr = w >= 1 ? blend.to : between(blend.from, blend.to, w);
  if (w >= 1) blend = null;  // reached: held until the next frame comes
  else state.blends += 1;  // (draws of an in-between, for tests)
  shown = fr;
  return fr;
}

function rate(list, now) {
  while (list.length && now - list[0] > 1000) list.shift();
  return list.length;
}

function onMessage(msg) {
  if (msg.type === 'hello') { state.hello = msg; if (state.ready) scene.useHello(msg); return; }
  if (msg.type === 'rate') {
    state.rate = msg.rate;
    steps = Math.max(1, Math.round(msg.rate / msg.fps));
    periodMs = 1000 / msg.fps;
    return;
  }
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
  const same = shown && shown.pose.length === msg.pose.length && shown.weights.length === msg.weights.length;
  blend = { from: steps > 1 && same ? shown : null, to: msg, t0: now };
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
  if (state.errors.length && options.hud) {
    $('problems').hidden = false;
    $('problems').textContent = state.errors.join('; ');
  }
}

function loop() {
  const now = performance.now();
  const live = state.ready && scene.feedReady;
  if (live && others.size) {
    others.forEach((msg, face) => { const c = copyFor(face); if (c) draw(c, msg); });
    others.clear();
    if (!pending) scene.render();
  }
  const fr = live ? frameNow(now) : null;
  if (pending && live) {
    state.lastFrame = pending.frame;
    state.faceFound = pending.face_found;
    pending = null;
  }
  if (fr) {
    draw(scene, fr);
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
  if (!state.ready) return;
  if (e.target.checked) look('face');
  else if (copies.length) place();
  else look(options.frame);
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
  if (options.orbit) {
    controls = new OrbitControls(scene.camera, scene.renderer.domElement);
    controls.addEventListener('change', () => scene.render());
  }
  resize();
  look(options.frame);
}).catch((e) => state.errors.push(String(e)));

// for tests and scripts
state.camera = () => ({
  position: scene.camera.position.toArray(), target: scene.target.toArray(), fov: scene.camera.fov,
});
state.between = between;
state.setSkeleton = (on) => { $('skel').checked = on; $('skel').dispatchEvent(new Event('change')); return on; };
connect();
requestAnimationFrame(loop);
