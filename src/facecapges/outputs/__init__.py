"""Outputs: where generated poses leave the system (BVH, face JSON, VMC, browser, video)."""
