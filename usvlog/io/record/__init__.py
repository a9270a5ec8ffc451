"""Live recording: sources (serial, UDP, TCP) -> power-loss-safe canonical MCAP log."""

from .output import check_outputs, part_path
from .recorder import Recorder
from .session import RecordSummary, open_sources, record
from .sources import Source, SourceSpec, parse_source
from .status import RecorderStatus, SourceStatus
from .topics import META_RECORDING

__all__ = ["META_RECORDING", "RecordSummary", "Recorder", "RecorderStatus", "Source", "SourceSpec", "SourceStatus",
           "check_outputs", "open_sources", "parse_source", "part_path", "record"]
