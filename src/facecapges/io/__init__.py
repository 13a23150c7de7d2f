"""Readers and writers of the file formats the project meets (BVH, WAV, BEAT face JSON, MP4), and
the static files every server of ours sends over HTTP (:mod:`.static_files`)."""
