"""Showing logs: the data drawn (data), the Rerun viewer (rrd) and the static HTML report (report).

The end of the pipeline, at the top of the library beside regress and under the API.
"""
