// The participant's page of `facecapges study serve`.
//
// One three.js scene (the project's AvatarScene from /web/avatar_scene.js) holds K copies
// of the study avatar side by side, all with the same face track and audio; copy j
// plays the motion the server hands out for screen position j. The page never learns
// which system that is. Positions are shown as letters A, B, … from the left; they
// mean nothing beyond "this position in this clip".
//
// Flow: invitation link (/?invite=TOKEN; the token is the participant's only credential)
// → (resume at the first unanswered clip) → for each clip: load,
// Play (replay allowed), rank on each criterion once watched to the end, Save and
// continue (no way back) → thank you. Every answer is stored by the server before
// the page moves on.
import { AvatarScene } from '/web/avatar_scene.js';
import { VrmScene } from '/web/vrm_scene.js';

const SPACING = 1.0; // metres between the avatars' roots
const REACH = 0.75; // metres an outstretched hand reaches sideways from an avatar's root
const PX_PER_AVATAR = 360, HEIGHT = 480;
const $ = (id) => document.getElementById(id);
const letter = (j) => String.fromCharCode(65 + j);

// inspected by tests and handy in the console; holds no system names (the page never has any)
const state = { screen: 'loading', participant: null, token: null, language: 'en', index: -1, total: 0, ready: false, watched: false,
                playing: false, plays: 0, frame: -1, draws: 0, audioClock: false, error: null };
window.study = state;

async function api(path, body) {
  const opts = body === undefined ? {} : {
    method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body) };
  const r = await fetch(path, opts);
  const doc = await r.json().catch(() => ({ error: `the server answered ${r.status}` }));
  if (!r.ok) throw Object.assign(new Error(doc.error || `the server answered ${r.status}`), { status: r.status });
  return doc;
}

function show(screen) {
  for (const id of ['loading', 'welcome', 'trial', 'done']) $(id).hidden = id !== screen;
  state.screen = screen;
}

function el(tag, props = {}, ...children) {
  const e = Object.assign(document.createElement(tag), props);
  e.append(...children);
  return e;
}

// ------------------------------------------------------------------ scene
let info = null, host = null, rigs = [];

async function buildScene(k) {
  const canvas = $('view');
  const width = PX_PER_AVATAR * k;
  host = new AvatarScene(canvas, { width, height: HEIGHT });
  const vrm = info.avatar === 'vrm';
  const glb = await (await fetch(vrm ? '/avatar.vrm' : '/avatar.glb')).arrayBuffer();
  for (let j = 0; vrm && j < k; j++) {
    // a VRM (three-vrm): its normalised bones and expressions are driven (facecapges.avatar.retarget)
    const rig = Object.create(VrmScene.prototype);
    rig.scene = host.scene;
    await rig.load(glb.slice(0));
    rig.vrm.scene.position.x = (j - (k - 1) / 2) * SPACING;
    rigs.push(rig);
  }
  for (let j = 0; !vrm && j < k; j++) {
    // a rig shares the host's scene: AvatarScene.load/setPose/setBlendshapes only touch
    // this.scene and the rig's own joints and morph meshes
    const rig = Object.create(AvatarScene.prototype);
    rig.scene = host.scene;
    await rig.load(glb.slice(0));
    rig.root.position.x = (j - (k - 1) / 2) * SPACING;
    rigs.push(rig);
  }
  // a long lens (narrow field of view from far away): the outer avatars are seen almost
  // from the front too, so no position shows its avatar from a more flattering angle
  const v = { target: [0, 0.36, 0], distance: 2.6, fov: 12 };
  if (vrm) v.target[1] += rigs[0].bonePosition('hips').y;  // a VRM stands on y = 0
  const halfH = Math.tan((v.fov * Math.PI) / 360) * (width / HEIGHT);
  v.distance = Math.max(v.distance, (((k - 1) / 2) * SPACING + REACH) / halfH);
  host.setView(v);
  $('labels').replaceChildren(...rigs.map((_, j) => el('span', { textContent: letter(j) })));
}

// ------------------------------------------------------------------ a trial's media and clock
let trial = null, face = null, motions = [], audioBuf = null, audioCtx = null, source = null;
let t0 = 0, wallStart = 0;

function draw(f) {
  const B = face.names.length;
  rigs.forEach((rig, j) => {
    if (rig.vrm) {
      rig.setPose(motions[j], f * rig.bones.length * 4);
      rig.setExpressions(face.weights, f * B);
      rig.update();
    } else {
      rig.setPose(motions[j], f * rig.joints.length * 4);
      rig.setBlendshapes(face.weights, f * B);
    }
  });
  host.render();
  state.frame = f;
  state.draws += 1;
}

function clock() {
  return state.audioClock ? audioCtx.currentTime - t0 : (performance.now() - wallStart) / 1000;
}

function tick() {
  requestAnimationFrame(tick);
  if (!state.ready || !state.playing) return;
  const t = clock();
  if (t >= trial.duration) {
    stopAudio();
    state.playing = false;
    draw(trial.frames - 1);
    onWatched();
    return;
  }
  const f = Math.min(trial.frames - 1, Math.max(0, Math.floor(t * trial.fps)));
  if (f !== state.frame) draw(f);
}

function stopAudio() {
  if (source) { try { source.stop(); } catch (e) { /* already stopped */ } source.disconnect(); source = null; }
}

async function play() {
  stopAudio();
  state.audioClock = false;
  if (audioCtx && audioBuf) {
    // resume() needs the click's user activation; never wait long for it
    await Promise.race([audioCtx.resume(), new Promise((r) => setTimeout(r, 300))]).catch(() => {});
    if (audioCtx.state === 'running') {
      source = audioCtx.createBufferSource();
      source.buffer = audioBuf;
      source.connect(audioCtx.destination);
      t0 = audioCtx.currentTime + 0.05;
      source.start(t0);
      state.audioClock = true;
    }
  }
  if (!state.audioClock) $('status').textContent = 'Sound could not start in this browser; the motion plays silently.';
  else $('status').textContent = state.watched ? 'Replaying…' : 'Playing…';
  wallStart = performance.now();
  state.playing = true;
  state.plays += 1;
  $('play').textContent = '↻ Replay';
  api('/api/event', { token: state.token, index: state.index, type: 'play' }).catch(() => {});
}

function onWatched() {
  if (!state.watched) {
    state.watched = true;
    $('ranking').disabled = false;
    for (const fs of $('ranking').querySelectorAll('fieldset')) fs.disabled = false;
  }
  $('status').textContent = 'Rank the avatars below (1 = best). You can replay the clip as often as you like.';
  updateSubmit();
}

async function loadTrial(index) {
  state.ready = false;
  state.watched = false;
  state.playing = false;
  state.plays = 0;
  stopAudio();
  $('play').disabled = true;
  $('play').textContent = '▶ Play';
  $('submit').disabled = true;
  $('trial-error').textContent = '';
  $('status').textContent = 'Loading the clip…';
  show('trial');
  state.index = index;
  $('progress').textContent = `Clip ${index + 1} of ${state.total}`;
  trial = await api(`/api/trial?token=${encodeURIComponent(state.token)}&index=${index}`);
  const [faceDoc, ...motionDocs] = await Promise.all([trial.face, ...trial.motions].map((u) => api(u)));
  face = { names: faceDoc.names, weights: new Float32Array(faceDoc.weights) };
  motions = motionDocs.map((m) => new Float32Array(m.quats));
  if (rigs[0] && rigs[0].vrm) rigs.forEach((rig) => rig.setLayout(motionDocs[0].bone_names, faceDoc.names));
  const wav = await (await fetch(trial.audio)).arrayBuffer();
  try {
    audioCtx = audioCtx || new AudioContext();
    audioBuf = await audioCtx.decodeAudioData(wav);
  } catch (e) {
    audioBuf = null;
  }
  buildRanking();
  draw(0);
  state.ready = true;
  $('play').disabled = false;
  $('status').textContent = 'Press Play to watch the clip.';
}

// ------------------------------------------------------------------ ranking form
function buildRanking() {
  const k = rigs.length;
  const form = $('ranking');
  form.replaceChildren(...info.criteria.map((c) => {
    const selects = rigs.map((_, j) => {
      const s = el('select', { name: `${c.key}-${j}` },
        el('option', { value: '', textContent: '–' }),
        ...Array.from({ length: k }, (_, r) => el('option', { value: String(r + 1), textContent: String(r + 1) })));
      s.dataset.criterion = c.key;
      s.dataset.position = String(j);
      s.dataset.previous = '';
      s.addEventListener('change', () => onRankChange(s));
      return el('label', {}, `${letter(j)} `, s);
    });
    const fs = el('fieldset', { disabled: true }, el('legend', {}, ...criterionName(c)),
      el('p', { className: 'def' }, ...criterionText(c)), el('div', { className: 'ranks' }, ...selects));
    fs.dataset.criterion = c.key;
    return fs;
  }));
}

// the criteria in the page's language (the Chinese text is the thesis's own wording)
function criterionName(c) {
  return state.language === 'zh' ? [el('span', { lang: 'zh', textContent: c.name_zh })] : [c.name];
}

function criterionText(c) {
  return state.language === 'zh' ? [el('span', { lang: 'zh', textContent: c.definition_zh })] : [c.definition];
}

function showCriteria() {
  $('criteria-intro').replaceChildren(...info.criteria.map((c) => el('p', { className: 'criterion-intro' },
    el('b', {}, ...criterionName(c)), el('br'), ...criterionText(c))));
  for (const fs of $('ranking').querySelectorAll('fieldset')) {
    const c = info.criteria.find((x) => x.key === fs.dataset.criterion);
    fs.querySelector('legend').replaceChildren(...criterionName(c));
    fs.querySelector('p.def').replaceChildren(...criterionText(c));
  }
}

function setLanguage(lang) {
  state.language = lang;
  document.documentElement.lang = lang;
  showCriteria();
}

function onRankChange(s) {
  // each rank once per criterion: the position that held the new rank gets this one's old rank
  const others = $('ranking').querySelectorAll(`select[data-criterion="${s.dataset.criterion}"]`);
  for (const o of others) {
    if (o !== s && o.value !== '' && o.value === s.value) {
      o.value = s.dataset.previous;
      o.dataset.previous = o.value;
    }
  }
  s.dataset.previous = s.value;
  updateSubmit();
}

function collectRanks() {
  const ranks = {};
  for (const c of info.criteria) {
    const sel = [...$('ranking').querySelectorAll(`select[data-criterion="${c.key}"]`)]
      .sort((a, b) => a.dataset.position - b.dataset.position);
    if (sel.some((s) => s.value === '')) return null;
    ranks[c.key] = sel.map((s) => Number(s.value));
  }
  return ranks;
}

function updateSubmit() {
  $('submit').disabled = !(state.watched && collectRanks());
}

async function submit() {
  const ranks = collectRanks();
  if (!state.watched || !ranks) return;
  $('submit').disabled = true;
  try {
    const st = await api('/api/answer', { token: state.token, index: state.index, ranks });
    stopAudio();
    state.playing = false;
    if (st.done) finish(); else await loadTrial(st.next);
  } catch (e) {
    state.error = e.message;
    if (e.status === 409) {
      // this clip was answered elsewhere (another tab, a double click): continue where the server is
      const st = await api('/api/session', { token: state.token }).catch(() => null);
      if (st && st.done) { finish(); return; }
      if (st && st.next !== state.index) { await loadTrial(st.next); return; }
    }
    $('trial-error').textContent = `Not saved: ${e.message}`;
    updateSubmit();
  }
}

function finish() {
  $('progress').textContent = `${state.total} of ${state.total} clips ranked`;
  show('done');
}

// ------------------------------------------------------------------ start
async function start() {
  $('start-error').textContent = '';
  $('start').disabled = true;
  try {
    const token = $('pid').value.trim();
    const st = await api('/api/session', { token });
    state.token = token;
    state.participant = st.participant;
    state.total = st.total;
    if (st.done) { finish(); return; }
    await loadTrial(st.next);
  } catch (e) {
    $('start-error').textContent = e.message;
    state.error = e.message;
    $('start').disabled = false;
  }
}

async function main() {
  info = await api('/api/info');
  $('n-clips').textContent = info.clips;
  $('n-versions').textContent = info.versions;
  const q = new URLSearchParams(location.search);
  state.language = info.languages.includes(q.get('lang')) ? q.get('lang') : info.language;
  $('language').value = state.language;
  $('language').addEventListener('change', () => setLanguage($('language').value));
  showCriteria();
  await buildScene(info.versions);
  if (q.get('invite')) $('pid').value = q.get('invite');
  $('start').addEventListener('click', start);
  $('pid').addEventListener('keydown', (e) => { if (e.key === 'Enter') start(); });
  $('play').addEventListener('click', play);
  $('submit').addEventListener('click', submit);
  requestAnimationFrame(tick);
  show('welcome');
}

main().catch((e) => {
  state.error = String(e && e.message || e);
  $('loading').textContent = `The study page could not start: ${state.error}`;
});
