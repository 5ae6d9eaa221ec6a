"""Depth on real footage: one module per cue, fused per frame (DESIGN.md "Depth on real footage").

* :mod:`.cues`     -- the shared record every cue returns (:class:`CueMap`) and unit helpers;
* :mod:`.parallax` -- depth from the camera's own motion (flow, essential matrix, triangulation);
* :mod:`.people`   -- person layers and their distance from face size (MediaPipe's bundled models);
* :mod:`.fuse`     -- edge-aware fusion of the cues with the network's dense prior into D.

The network itself stays in :mod:`rvr_addon.estimate`. Nothing here imports bpy.
"""
