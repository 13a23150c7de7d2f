"""BEAT data: file naming and splits, per-clip readers, the prepared cache."""
