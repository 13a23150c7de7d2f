"""The FaceCapGes gesture model (thesis ch. 3), its checkpoint and the streaming generator."""
