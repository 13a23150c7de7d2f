"""VRM: the avatar written as VRM 1.0, and any VRM 0.x / 1.0 (or humanoid GLB) read back.

VRM is glTF 2.0 binary + the ``VRMC_vrm`` extension (1.0) or the ``VRM`` extension
(0.x): a map from humanoid bone names (``hips``, ``leftUpperArm`` …) to glTF nodes,
named facial expressions bound to morph targets, eye control and licence metadata.
Specification: vrm-c/vrm-specification, ``specification/VRMC_vrm-1.0``.

Modules, one per concept (VRM 1.0 and 0.x side by side in each, as ``@pixiv/three-vrm`` keeps them):

* :mod:`~facecapges.avatar.vrm.humanoid` — bone names and hierarchy, BEAT's bones;
* :mod:`~facecapges.avatar.vrm.expressions` — ARKit weights → VRM presets and perfect-sync names,
  the presets of our avatar, :class:`~facecapges.avatar.vrm.expressions.ExpressionMap`;
* :mod:`~facecapges.avatar.vrm.meta` — name, authors, licence;
* :mod:`~facecapges.avatar.vrm.glb` — the binary glTF container, node rest matrices;
* :mod:`~facecapges.avatar.vrm.write` — our avatar as a ``.vrm`` (1.0 or 0.x);
* :mod:`~facecapges.avatar.vrm.read` — any ``.vrm`` / humanoid ``.glb`` read and checked (:class:`~facecapges.avatar.vrm.read.VrmModel`);
* :mod:`~facecapges.avatar.vrm.animation` — gestures (+ face) as VRM Animation (``.vrma``);
* :mod:`~facecapges.avatar.vrm.view` — a VRM driven by BEAT motion and rendered by three-vrm.
"""
