// Play a BVH with three.js (BVHLoader + AnimationMixer, as a web app would) and print the
// world positions of some bones at some times as JSON: {"<time>": {"<bone>": [x, y, z]}}.
// Usage: node scripts/bvh-three-pose.mjs FILE.bvh TIME[,TIME...] BONE[,BONE...]   (from the repo root)
import { readFileSync } from 'node:fs';
import { AnimationMixer, Vector3 } from 'three';
import { BVHLoader } from 'three/examples/jsm/loaders/BVHLoader.js';

const result = new BVHLoader().parse(readFileSync(process.argv[2], 'utf8'));
const times = process.argv[3].split(',').map(Number);
const wanted = process.argv[4].split(',');
const root = result.skeleton.bones[0];
const mixer = new AnimationMixer(root);
mixer.clipAction(result.clip).play();
const out = {};
for (const t of times) {
  mixer.setTime(t);
  root.updateMatrixWorld(true);
  const at = {};
  for (const b of result.skeleton.bones) {
    if (wanted.includes(b.name)) at[b.name] = b.getWorldPosition(new Vector3()).toArray();
  }
  out[String(t)] = at;
}
console.log(JSON.stringify(out));
