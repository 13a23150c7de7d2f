// FaceCapGes avatar scene: a reusable ES module (three.js 0.187.0).
//
// Loads the avatar .glb written by `facecapges avatar build` and shows it driven by
// one frame at a time:
//   * pose: the LOCAL rotation of every BEAT joint as a unit quaternion, real part
//     first (w, x, y, z) — the project's convention (facecapges.rotations) — in the
//     order of `scene.jointNames` (the BEAT BVH joint order, stored in the glb);
//     a joint's glTF rest rotation is the identity, so this is the BVH rotation as is;
//   * face: the 52 ARKit blendshape weights in [0, 1], in the order of
//     `scene.blendshapeNames` (facecapges.arkit.ARKIT_NAMES, stored in the glb).
// Used by the offline renderer (render.html, headless Chromium) and by the browser
// viewer (viewer.html). The page must map "three" and "three/addons/" in an import map.
//
// The avatar-scene interface both pages use, which vrm_scene.js (a VRM, three-vrm) implements too:
//   open(layout?)         load the avatar the page's server holds (here /avatar.glb); resolves to a list
//                         of problems (names the avatar lacks), empty when all is well
//   describe()            what was loaded (counts and names, for tests and the render's checks)
//   label                 a one-line name for the viewer's HUD
//   frameSize             {pose: joints, face: weights}: the length of one frame's arrays
//   setPose(q, off)       one frame's LOCAL quaternions (w, x, y, z), frameSize.pose of them from q[off]
//   setFace(w, off)       one frame's face weights, frameSize.face of them from w[off]
//   restPose()            every driven joint at rest
//   feedMessage           the live feed message this avatar draws ('pose' here, 'vrm_pose' for a VRM)
//   useHello(hello)       the live feed's `hello` (its joint and blendshape names), see setLayout
//   feedReady             true once a live feed message can be drawn
//   copy()                another avatar of the same model in the scene (live --faces N), or null
//   bonePosition(name)    world position of a joint (null if the model lacks it)
//   view(name)            a camera view ({target, distance, fov}): 'body' / 'face' (the scene's own), or one of
//                         FRAMES framed on the avatar's rest proportions (`rest`, see measure())
//   setView(name or view), target (what the camera looks at), render(), and the renderer, camera and scene
// The constructor's `background`: a colour, or null for a transparent canvas (alpha 0 where nothing is drawn).
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import * as SkeletonUtils from 'three/addons/utils/SkeletonUtils.js';

export const VIEWS = {
  // camera target (x, y, z) and distance in metres, vertical field of view in degrees
  body: { target: [0, 0.36, 0.0], distance: 2.6, fov: 30 },
  face: { target: [0, 0.752, 0.06], distance: 0.46, fov: 30 },
};

// the framings a page can ask for (the viewer's `frame=` URL parameter): head and shoulders, the upper body
// to the hips, the whole avatar
export const FRAMES = ['head', 'upper', 'full'];

// the view of `frame` (FRAMES) for an avatar of rest proportions `r` (AvatarScene.measure) through a camera of
// aspect `aspect`: the span from the avatar's top down to the frame's bottom, and the frame's width, fill the
// picture (5 % margin above and below)
export function frameView(r, frame, aspect, fov = 30) {
  let bottom, halfWidth;
  if (frame === 'head') {  // down to the chest: 0.6 of the top-to-shoulders height below the shoulders
    bottom = r.shoulders - 0.6 * (r.top - r.shoulders);
    halfWidth = 1.5 * r.halfWidth;
  } else if (frame === 'upper') {  // down to just below the hips, wide enough for the hands in front of the body
    bottom = r.hips - 0.1 * (r.top - r.hips);
    halfWidth = 2.4 * r.halfWidth;
  } else {
    bottom = r.bottom;
    halfWidth = 2.4 * r.halfWidth;
  }
  const pad = 0.05 * (r.top - bottom), hi = r.top + pad, lo = bottom - pad;
  const t = Math.tan((fov * Math.PI) / 360);
  const distance = Math.max((hi - lo) / 2 / t, halfWidth / (t * aspect));
  return { target: [r.x, (hi + lo) / 2, r.z], distance, fov };
}

export class AvatarScene {
  // inset: also draw the face close-up (VIEWS.face, following the head) in the top-right corner
  constructor(canvas, { width = 640, height = 480, background = 0xeef0f3, antialias = true, inset = false } = {}) {
    this.inset = inset;
    this.faceCamera = new THREE.PerspectiveCamera(VIEWS.face.fov, 4 / 3, 0.01, 50);
    const alpha = background === null;
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias, alpha, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(1);
    this.renderer.setSize(width, height, false);
    this.renderer.outputColorSpace = THREE.SRGBColorSpace;
    if (alpha) this.renderer.setClearColor(0x000000, 0);
    this.scene = new THREE.Scene();
    this.scene.background = alpha ? null : new THREE.Color(background);
    this.camera = new THREE.PerspectiveCamera(30, width / height, 0.01, 50);
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x8a8078, 1.6));
    const key = new THREE.DirectionalLight(0xffffff, 2.2);
    key.position.set(1.2, 1.5, 1.6);
    this.scene.add(key);
    const fill = new THREE.DirectionalLight(0xdde6ff, 0.7);
    fill.position.set(-1.5, 0.6, 1.0);
    this.scene.add(fill);
    const rim = new THREE.DirectionalLight(0xffffff, 0.6);
    rim.position.set(0, 1.5, -2.0);
    this.scene.add(rim);
    this.jointNames = [];
    this.blendshapeNames = [];
    this.joints = [];
    this.morphMeshes = [];
    this.helloSeen = false;
    this.setView('body');
  }

  get label() { return 'FaceCapGes avatar (glTF)'; }
  // the joints measure() frames by: the head, the two upper arms (the shoulders) and the hips
  get landmarkBones() { return { head: 'Head', left: 'LeftArm', right: 'RightArm', hips: 'Hips' }; }
  get feedMessage() { return 'pose'; }
  get feedReady() { return this.helloSeen; }
  get frameSize() { return { pose: this.poseNodes.length, face: this.faceIndex.length }; }

  // the page's avatar (or `url`); our avatar lacks nothing it names, so no problems
  async open(layout = null, url = '/avatar.glb') {
    await this.load(url);
    return [];
  }

  describe() {
    return {
      joints: this.jointNames.length, blendshapes: this.blendshapeNames.length, morphMeshes: this.morphMeshes.length,
      jointNames: this.jointNames, blendshapeNames: this.blendshapeNames,
    };
  }

  // which joints / blendshapes (by name) a frame's arrays hold; load() sets the avatar's own order.
  // Names the avatar lacks are skipped (their joints stay at rest).
  setLayout(jointNames, blendshapeNames) {
    const byName = new Map(this.jointNames.map((n, i) => [n, this.joints[i]]));
    this.poseNodes = jointNames.map((n) => byName.get(n) || null);
    const bIdx = new Map(this.blendshapeNames.map((n, i) => [n, i]));
    this.faceIndex = blendshapeNames.map((n) => (bIdx.has(n) ? bIdx.get(n) : -1));
  }

  useHello(hello) {
    this.setLayout(hello.joints, hello.blendshapes);
    this.helloSeen = true;
  }

  // source: a URL or an ArrayBuffer holding the .glb
  async load(source) {
    const loader = new GLTFLoader();
    const gltf = typeof source === 'string'
      ? await loader.loadAsync(source)
      : await new Promise((res, rej) => loader.parse(source, '', res, rej));
    this.gltf = gltf;
    this.root = gltf.scene;
    this.scene.add(this.root);
    const extras = (gltf.parser.json.extras || {}).facecapges || {};
    this.jointNames = extras.joint_names || [];
    this.blendshapeNames = extras.blendshape_names || [];
    const byName = this.bind(this.root);
    const missing = this.jointNames.filter((n, i) => !this.joints[i]);
    if (missing.length) throw new Error(`avatar is missing joints ${missing.join(', ')}`);
    this.root.traverse((o) => { if (o.isMesh) o.frustumCulled = false; });
    this.setLayout(this.jointNames, this.blendshapeNames);
    // the face close-up keeps its rest framing relative to the Head joint, wherever the body takes it
    this.head = byName.Head || null;
    if (this.head) {
      this.root.updateMatrixWorld(true);
      const h = this.head.getWorldPosition(new THREE.Vector3());
      this.faceOffset = new THREE.Vector3(...VIEWS.face.target).sub(h);
    }
    this.rest = this.measure();
    return this;
  }

  // the avatar's proportions as it stands now (at rest when load() calls it), in world metres, for frameView:
  // the top and bottom of its meshes (skinned vertices), the heights of the head joint, the shoulders and the
  // hips, half the shoulders' width, and where the camera aims (x of the hips, z of the head); null when the
  // avatar lacks a landmark joint or a mesh
  measure() {
    const names = this.landmarkBones;
    this.root.updateMatrixWorld(true);
    const box = new THREE.Box3().setFromObject(this.root, true);
    const head = this.bonePosition(names.head), hips = this.bonePosition(names.hips);
    const l = this.bonePosition(names.left), r = this.bonePosition(names.right);
    if (box.isEmpty() || !head || !hips || !l || !r) return null;
    return {
      top: Math.max(box.max.y, head.y + 0.1), bottom: box.min.y, head: head.y, shoulders: (l.y + r.y) / 2,
      hips: hips.y, halfWidth: Math.abs(l.x - r.x) / 2, x: hips.x, z: head.z,
    };
  }

  // this avatar's joints and face primitives in `root` (its model or a copy of it); returns nodes by name
  bind(root) {
    this.root = root;
    const byName = {};
    root.traverse((o) => { if (!(o.name in byName)) byName[o.name] = o; });
    this.joints = this.jointNames.map((n) => byName[n]);
    this.morphMeshes = [];
    root.traverse((o) => { if (o.isMesh && o.morphTargetDictionary) this.morphMeshes.push(o); });
    // map each blendshape name to its morph index in every face primitive
    this.morphIndex = this.morphMeshes.map((m) => this.blendshapeNames.map((n) => m.morphTargetDictionary[n]));
    return byName;
  }

  // a view by name: 'body' or 'face' (VIEWS), a frame of FRAMES (from the rest proportions; 'body' when the
  // avatar could not be measured); a view object as it is
  view(name) {
    if (typeof name !== 'string') return name;
    if (FRAMES.includes(name)) return this.rest ? frameView(this.rest, name, this.camera.aspect) : VIEWS.body;
    return VIEWS[name] || VIEWS.body;
  }

  setView(name) {
    const v = this.view(name);
    this.target = new THREE.Vector3(...v.target);
    this.camera.fov = v.fov;
    this.camera.position.set(v.target[0], v.target[1], v.target[2] + v.distance);
    this.camera.lookAt(this.target);
    this.camera.updateProjectionMatrix();
  }

  // quats: flat array, 4 per joint (w, x, y, z), in the layout's order (jointNames unless setLayout
  // said otherwise); offset: start index
  setPose(quats, offset = 0) {
    for (let j = 0; j < this.poseNodes.length; j++) {
      const n = this.poseNodes[j], k = offset + 4 * j;
      if (n) n.quaternion.set(quats[k + 1], quats[k + 2], quats[k + 3], quats[k]);
    }
  }

  restPose() {
    for (const n of this.poseNodes) if (n) n.quaternion.identity();
  }

  // weights: flat array in the layout's blendshape order; the avatar's blendshapes it does not name are 0
  setFace(weights, offset = 0) {
    const w = new Array(this.blendshapeNames.length).fill(0);
    this.faceIndex.forEach((b, k) => { if (b >= 0) w[b] = weights[offset + k]; });
    this.setBlendshapes(w);
  }

  bonePosition(name) {
    const i = this.jointNames.indexOf(name);
    return i >= 0 ? this.joints[i].getWorldPosition(new THREE.Vector3()) : null;
  }

  // another avatar: a clone of the model in this scene, driven in the same layout
  copy() {
    const rig = Object.create(AvatarScene.prototype);
    rig.jointNames = this.jointNames;
    rig.blendshapeNames = this.blendshapeNames;
    rig.bind(SkeletonUtils.clone(this.root));
    this.scene.add(rig.root);
    const poseNames = this.poseNodes.map((n) => (n ? n.name : ''));
    const faceNames = this.faceIndex.map((b) => (b >= 0 ? this.blendshapeNames[b] : ''));
    rig.setLayout(poseNames, faceNames);
    return rig;
  }

  // weights: flat array in blendshapeNames order; offset: start index
  setBlendshapes(weights, offset = 0) {
    this.morphMeshes.forEach((m, mi) => {
      const idx = this.morphIndex[mi];
      for (let b = 0; b < idx.length; b++) {
        if (idx[b] !== undefined) m.morphTargetInfluences[idx[b]] = weights[offset + b];
      }
    });
  }

  render() {
    const r = this.renderer;
    if (!this.inset || !this.head) { r.render(this.scene, this.camera); return; }
    const size = r.getSize(new THREE.Vector2());
    r.setScissorTest(false);
    r.setViewport(0, 0, size.x, size.y);
    r.render(this.scene, this.camera);
    // the inset: a third of the height, 4:3, top-right, with a thin frame (viewport origin = bottom-left)
    const ih = Math.round(size.y / 3), iw = Math.round(ih * 4 / 3), m = Math.round(size.y / 60) + 2;
    const x = size.x - iw - m, y = size.y - ih - m;
    this.root.updateMatrixWorld(true);
    const t = this.head.getWorldPosition(new THREE.Vector3()).add(this.faceOffset);
    const v = VIEWS.face;
    this.faceCamera.aspect = iw / ih;
    this.faceCamera.position.set(t.x, t.y, t.z + v.distance);
    this.faceCamera.lookAt(t);
    this.faceCamera.updateProjectionMatrix();
    r.setScissorTest(true);
    const clear = r.getClearColor(new THREE.Color()), alpha = r.getClearAlpha();
    r.setClearColor(0x6b7280, 1);
    r.setScissor(x - 2, y - 2, iw + 4, ih + 4);
    r.setViewport(x - 2, y - 2, iw + 4, ih + 4);
    r.clear();
    r.setClearColor(clear, alpha);
    r.setScissor(x, y, iw, ih);
    r.setViewport(x, y, iw, ih);
    r.render(this.scene, this.faceCamera);
    r.setScissorTest(false);
    r.setViewport(0, 0, size.x, size.y);
  }
}

export default AvatarScene;
