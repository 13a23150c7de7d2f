// FaceCapGes VRM scene: any VRM 0.x / 1.0 avatar loaded by @pixiv/three-vrm 3.5.5 (three.js 0.187.0).
//
// Driven one frame at a time, in the layout facecapges.avatar.retarget writes:
//   * pose: for each name of `bones` (VRM 1.0 humanoid bone names) the LOCAL rotation of that
//     *normalised* bone (vrm.humanoid.getNormalizedBoneNode) as a quaternion, real part first
//     (w, x, y, z); VRM 0.x models are turned to face +Z (VRMUtils.rotateVRM0) as three-vrm does;
//   * face: for each name of `expressions` its weight in [0, 1] (vrm.expressionManager).
// vrm.update() then moves the raw bones and morph targets. LookAt is not automatic: the face
// weights carry the eye movement. The page must map "three", "three/addons/" and
// "@pixiv/three-vrm" in an import map (and "@pixiv/three-vrm-animation" to play a .vrma).
// It implements the avatar-scene interface of avatar_scene.js: the live viewer and the render page
// drive it as they drive our avatar.
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { VRMLoaderPlugin, VRMUtils } from '@pixiv/three-vrm';
import { AvatarScene } from './avatar_scene.js';

// the renderer, lights and camera are AvatarScene's (avatar_scene.js); loading, framing and posing are VRM's
export class VrmScene extends AvatarScene {
  constructor(canvas, options = {}) {
    super(canvas, options);
    this.bones = [];
    this.boneNodes = [];
    this.expressions = [];
  }

  get label() { return (this.vrm.meta.name || this.vrm.meta.title || 'VRM') + ` (VRM ${this.metaVersion})`; }
  // the live feed's `vrm_pose` messages are already in the layout of /vrm/layout.json; its `hello` is not used
  get feedMessage() { return 'vrm_pose'; }
  get feedReady() { return !!this.vrm; }
  get frameSize() { return { pose: this.bones.length, face: this.expressions.length }; }
  useHello() {}
  copy() { return null; }

  // the page's VRM (/avatar.vrm) in `layout` ({"bones", "expressions"}; fetched from /vrm/layout.json
  // without one); resolves to the names three-vrm does not have
  async open(layout = null, url = '/avatar.vrm') {
    const lay = layout || await (await fetch('/vrm/layout.json')).json();
    await this.load(url);
    const missing = this.setLayout(lay.bones, lay.expressions);
    this.setView('body');
    return [
      ...(missing.bones.length ? [`three-vrm has no normalised bones ${missing.bones.join(', ')}`] : []),
      ...(missing.expressions.length ? [`three-vrm has no expressions ${missing.expressions.join(', ')}`] : []),
    ];
  }

  describe() {
    const em = this.vrm.expressionManager;
    return {
      joints: this.bones.length, blendshapes: this.expressions.length, metaVersion: this.metaVersion,
      humanBones: Object.keys(this.vrm.humanoid.humanBones).filter((n) => this.vrm.humanoid.getRawBoneNode(n)),
      expressionNames: em ? em.expressions.map((e) => e.expressionName) : [],
      metaName: this.vrm.meta.name || this.vrm.meta.title || null,
    };
  }

  // source: a URL or an ArrayBuffer holding the .vrm
  async load(source) {
    const loader = new GLTFLoader();
    loader.register((parser) => new VRMLoaderPlugin(parser));
    const gltf = typeof source === 'string'
      ? await loader.loadAsync(source)
      : await new Promise((res, rej) => loader.parse(source, '', res, rej));
    const vrm = gltf.userData.vrm;
    if (!vrm) throw new Error('not a VRM: @pixiv/three-vrm found no VRM extension');
    this.gltf = gltf;
    this.vrm = vrm;
    VRMUtils.rotateVRM0(vrm);
    if (vrm.lookAt) vrm.lookAt.autoUpdate = false;
    vrm.scene.traverse((o) => { if (o.isMesh) o.frustumCulled = false; });
    this.scene.add(vrm.scene);
    vrm.update(0);
    vrm.scene.updateMatrixWorld(true);
    // for AvatarScene's face inset: the camera follows the head bone, aimed a little above it
    this.root = vrm.scene;
    this.head = vrm.humanoid.getRawBoneNode('head');
    this.faceOffset = new THREE.Vector3(0, 0.07, 0);
    this.rest = this.measure();
    if (this.camera) this.setView('body');  // (a rig sharing another scene has no camera)
    return this;
  }

  get metaVersion() { return this.vrm.meta.metaVersion; }

  // world position of a raw humanoid bone (null if the model lacks it)
  bonePosition(name) {
    const n = this.vrm.humanoid.getRawBoneNode(name);
    return n ? n.getWorldPosition(new THREE.Vector3()) : null;
  }

  get landmarkBones() { return { head: 'head', left: 'leftUpperArm', right: 'rightUpperArm', hips: 'hips' }; }

  // the body view frames the avatar's own top (its head and hair, however large) to below the hips, and
  // both hands at rest; the face view the head; FRAMES as AvatarScene does
  view(name) {
    if (!this.vrm || (name !== 'face' && name !== 'body')) return super.view(name);
    const head = this.bonePosition('head'), hips = this.bonePosition('hips');
    const l = this.bonePosition('leftHand'), r = this.bonePosition('rightHand');
    const fov = 30;
    let target, distance;
    if (name === 'face') {
      target = head.clone().add(new THREE.Vector3(0, 0.07, 0));
      distance = 0.55;
    } else {
      const top = this.rest ? Math.max(this.rest.top + 0.05, head.y + 0.1) : head.y + 0.25;
      const bottom = hips.y - 0.2;
      target = new THREE.Vector3(0, (top + bottom) / 2, 0);
      const halfH = (top - bottom) / 2, halfW = Math.abs(l.x - r.x) / 2 + 0.1;
      const t = Math.tan((fov / 2) * Math.PI / 180);
      distance = Math.max(halfH / t, halfW / (t * this.camera.aspect)) * 1.05;
    }
    return { target: target.toArray(), distance, fov };
  }

  // which normalised bones / expressions the flat arrays hold
  setLayout(bones, expressions) {
    this.bones = bones;
    this.boneNodes = bones.map((n) => this.vrm.humanoid.getNormalizedBoneNode(n));
    this.expressions = expressions;
    const em = this.vrm.expressionManager;
    this.missing = {
      bones: bones.filter((n, i) => !this.boneNodes[i]),
      expressions: expressions.filter((n) => !em || !em.getExpression(n)),
    };
    return this.missing;
  }

  // quats: flat (w, x, y, z) per bone of the layout; offset: start index
  setPose(quats, offset = 0) {
    for (let i = 0; i < this.boneNodes.length; i++) {
      const n = this.boneNodes[i];
      const k = offset + 4 * i;
      if (n) n.quaternion.set(quats[k + 1], quats[k + 2], quats[k + 3], quats[k]);
    }
  }

  restPose() {
    for (const n of this.boneNodes) if (n) n.quaternion.identity();
  }

  setFace(weights, offset = 0) { this.setExpressions(weights, offset); }

  setExpressions(weights, offset = 0) {
    const em = this.vrm.expressionManager;
    if (!em) return;
    for (let i = 0; i < this.expressions.length; i++) em.setValue(this.expressions[i], weights[offset + i]);
  }

  update() {
    this.vrm.update(0);
    this.vrm.scene.updateMatrixWorld(true);
  }

  // a .vrma played by @pixiv/three-vrm-animation on this VRM (seekVrma poses it)
  async playVrma(url) {
    const { VRMAnimationLoaderPlugin, createVRMAnimationClip } = await import('@pixiv/three-vrm-animation');
    const loader = new GLTFLoader();
    loader.register((parser) => new VRMAnimationLoaderPlugin(parser));
    const gltf = await loader.loadAsync(url);
    const anims = gltf.userData.vrmAnimations || [];
    if (!anims.length) throw new Error('no VRM animation in ' + url);
    const clip = createVRMAnimationClip(anims[0], this.vrm);
    this.mixer = new THREE.AnimationMixer(this.vrm.scene);
    this.mixer.clipAction(clip).play();
    return { duration: clip.duration, tracks: clip.tracks.length, trackNames: clip.tracks.map((t) => t.name),
             humanoidTracks: anims[0].humanoidTracks.rotation.size,
             expressionTracks: anims[0].expressionTracks.preset.size + anims[0].expressionTracks.custom.size };
  }

  // the pose at time t of the .vrma playVrma loaded
  seekVrma(t) {
    this.mixer.setTime(t);
    this.update();
  }

  expressionValue(name) {
    const em = this.vrm.expressionManager;
    return em ? em.getValue(name) : null;
  }

  render() {
    this.update();
    super.render();  // the body view (+ the face inset when the scene was made with inset: true)
  }
}

export default VrmScene;
