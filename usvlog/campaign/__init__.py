"""Field campaigns: many runs through the pipeline on Dask, drift across a season, one report.

* :mod:`.tasks`: a run's sources, settings, key and the task that takes it through the stages;
* :mod:`.columns`: the one adapter from a stage's result object to table columns;
* :mod:`.engine`: the Dask runner (a local cluster of processes, or an existing scheduler);
* :mod:`.table`: ``runs.parquet``;
* :mod:`.drift`: consistency and change-point statistics (pure, no Dask);
* :mod:`.core`: :func:`~usvlog.campaign.core.run_campaign`, the whole campaign;
* :mod:`.report`: ``campaign.html``, the drift PNGs and ``campaign.rrd``.

Nothing is imported here, so that ``import usvlog.campaign.drift`` stays light.
"""
