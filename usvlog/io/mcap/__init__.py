"""Canonical MCAP logs: write a FieldLog, read one back (recovering damaged files).

Layout written: header, metadata records (datum, vessel, provenance: first, so a
truncated file keeps them), schema and channel records, then zstd chunks each holding one
channel's messages (JSON; little-endian CDR with a ros2msg schema for the bulk derived
channels, :data:`usvlog.log.channels.BULK_TOPICS`) in log-time order, chunks of different
channels overlapping in time (a reader merges them: the mcap library's
``iter_messages(log_time_order=True)`` does), then the usual summary (indexes, statistics).
A read of some channels skips the others' chunks by the chunk index; a copy of a file's
channels into another takes their chunks whole. Each message's ``sequence`` is its row
number in the channel's frame so reading restores the frame's row order.
:class:`McapWriter` is the one writer: ``write_log`` writes a whole log through it,
the importer streams batches into it (its metadata then follows the chunks).

Writing builds the message and index records with compiled loops
(``usvlog._kernels``) and gives the same bytes as the mcap library's ``Writer`` fed the
same chunks (``_write_log_reference``, kept to test against).

Reading walks the records itself rather than through the mcap library's
per-record objects and checks every chunk's CRC (and the data section's): a chunk
that fails is never loaded; after a damaged record the walk resumes at the next
chunk that checks out (from the summary's chunk index, else by looking for chunk
headers), so every intact chunk is kept wherever the damage is, and what was lost
is reported (``FieldLog.recovery``). ``_scan_fast`` walks records and messages into arrays with compiled loops;
``_scan_reference`` is the plain one-record-at-a-time reading, kept as the
reference the tests compare it with.
"""

from .reader import read_log, read_logs, scan_file
from .writer import McapWriter, write_log

__all__ = ["McapWriter", "read_log", "read_logs", "scan_file", "write_log"]
