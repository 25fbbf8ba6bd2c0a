"""Local mapping: keyframes, landmarks, the covisibility graph, culling and bundle adjustment."""
