"""Training the gesture model: closed-loop sliding-window rollout (thesis ch. 4)."""
