"""Readers and writers of the file formats the project meets (BVH, WAV, BEAT face JSON)."""
