"""``rvr refocus CLIP -o OUT.mp4``: the whole product in one command.

A phone clip in, a refocused video out: (proxy: resize / trim) -> estimate D and E (the depth
system) -> stabilize -> look-ahead autofocus (or a pinned subject) -> render, then optionally a
before | after video and a contact sheet. Each stage is the engine's own job; :class:`JobChain`
runs them as one job (step, cancel, progress), so the CLI, Dask and Blender drive it alike.
"""

DEFAULT_MAX_SIZE = 1280
"""Long side (px) the pipeline works at unless told otherwise (``--max-size 0``: the clip's own)."""
