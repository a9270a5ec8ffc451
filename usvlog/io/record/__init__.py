"""Live recording: sources (serial, UDP, TCP) -> power-loss-safe canonical MCAP log."""

from .recorder import (
           META_RECORDING,
           Recorder,
           RecorderStatus,
           SourceStatus,
           check_outputs,
           part_path,
)
from .session import RecordSummary, open_sources, record
from .sources import Source, SourceSpec, parse_source

__all__ = ["META_RECORDING", "Recorder", "check_outputs", "RecorderStatus", "SourceStatus", "part_path", "RecordSummary",
           "open_sources", "record", "Source", "SourceSpec", "parse_source"]
