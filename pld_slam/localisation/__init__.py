"""Localisation: a frame posed against the map.

`local_map` gathers the landmarks of a frame's neighbourhood in the map and poses the frame
against them (the paper's Track_d against the local map, ORB-SLAM2's TrackLocalMap);
`static_world` re-solves a pose that movers pulled for the static world's motion. Tracking
calls them for every frame, loop verification for a loop candidate's map: one layer below
both stages, so that neither imports the other.
"""
