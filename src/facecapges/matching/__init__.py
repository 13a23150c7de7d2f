"""The motion-matching gesture engine: replays the speaker's real motion, steered by the speech.

Beside :mod:`facecapges.network` (the thesis network): both engines turn per-frame audio, face and
head into upper-body poses (47, 6) rot6d at the model rate, behind the same generator interface.
"""
