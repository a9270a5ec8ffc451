"""Field logs in memory: the canonical channels (JSON Schema -> DataFrame columns), FieldLog, summaries.

Above :mod:`usvlog.model` and below every stage that reads or makes a log (estimate,
identify, control, sim, replay); files are read and written by :mod:`usvlog.io`.
"""
