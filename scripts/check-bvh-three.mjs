// Parse a BVH file with three.js's own BVHLoader (the loader a web app would use) and
// print what it found as JSON: bones (joints + end sites), animation tracks, duration.
// Usage: node scripts/check-bvh-three.mjs FILE.bvh   (run from the repository root)
import { readFileSync } from 'node:fs';
import { BVHLoader } from 'three/examples/jsm/loaders/BVHLoader.js';

const result = new BVHLoader().parse(readFileSync(process.argv[2], 'utf8'));
const names = result.skeleton.bones.map((b) => b.name);
console.log(JSON.stringify({
  bones: names.length,
  names,
  tracks: result.clip.tracks.length,
  duration: result.clip.duration,
}));
