"""Loop closing: GGS place recognition, candidate verification, loop correction and the pose graph."""
