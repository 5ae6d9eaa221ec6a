"""``rvr batch``: analyze -> autofocus -> render for many clips as one Dask task graph.

The batch never re-implements a stage: every task runs the engine's own job classes
(:class:`~rvr_addon.estimate.infer.EstimateJob`, :class:`~rvr_addon.temporal.job.StabilizeJob`,
:class:`~rvr_addon.laaf.lookahead.AutofocusJob`, :class:`~rvr_addon.pipeline.RenderJob`) on a
frame range of one clip. What this package adds is the plan around them:

* :mod:`.inputs`: which clips (arguments, folders, list files) and their output names;
* :mod:`.chunks`: frame ranges and the overlap each stage reads beyond its range;
* :mod:`.staging`: per-chunk staging caches, so that every per-clip cache has one writer;
* :mod:`.stages`: the task functions a worker runs (one stage of one chunk each);
* :mod:`.worker`: the worker plugin that loads the estimator once per worker process;
* :mod:`.graph`: the client side: cluster, task graph, progress bar, results;
* :mod:`.report`: done markers (re-runs skip finished clips) and the summary table;
* :mod:`.commands`: the ``rvr batch`` command line.

No module imports bpy; dask is imported only by :mod:`.graph`, :mod:`.worker` and the CLI.
"""

FORMATS = ("mp4", "png", "exr")
"""Output formats of ``rvr batch --format`` (here, light: ``rvr batch --help`` lists them)."""
