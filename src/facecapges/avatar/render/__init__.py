"""Rendering the avatar with three.js in headless Chromium (real WebGL, software GL)."""
