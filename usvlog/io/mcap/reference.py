"""Reference paths the compiled MCAP code is tested against: the mcap library's Writer
(one ``add_message`` per message) and a plain one-record-at-a-time scan."""

from __future__ import annotations

import struct

import numpy as np

from ..._version import __version__
from ...errors import InputError
from ...log.fieldlog import FieldLog
from ..atomic import atomic_path
from .codec import Codec
from .container import (
    _add_message,
    _apply,
    _check_message_index,
    _chunk_data,
    _chunk_records,
    _CorruptChunk,
    _layout,
    _parse,
    _Scan,
    _summary_channel,
)
from .decode import _read_log
from .format import (
    _REC,
    OP_CHUNK,
    OP_DATA_END,
    OP_FOOTER,
    OP_MESSAGE,
    OP_MESSAGE_INDEX,
)
from .recovery import (
    _chunk_shape,
    _finish,
    _next_chunk_reference,
    _note_region,
    _region_reason,
    _resync,
    _unexpected,
)
from .writer import _codec_for, _compression, _schema_record


def _schema_records(log: FieldLog) -> tuple[list, list, list, list[tuple[str, dict, Codec]]]:
    """(mcap Schema records, Channel records, both in registration order, and
    [(topic, schema, codec)] in channel-id order) -- for the reference writer."""
    # start-up: the mcap library loads only for the reference paths
    from mcap.records import Channel, Schema

    schemas, channels, both, out, ids = [], [], [], [], {}
    for topic in log.channels:   # ids in the log's channel order, as write_log gives them
        schema, codec = _codec_for(topic, log.schemas.get(topic), log.channels[topic])
        sname, senc, sdata = _schema_record(topic, schema, codec)
        key = (sname, sdata)
        if key not in ids:
            ids[key] = len(schemas) + 1
            schemas.append(Schema(id=ids[key], name=sname, encoding=senc, data=sdata))
            both.append(schemas[-1])
        channels.append(Channel(id=len(channels) + 1, topic=topic, message_encoding=codec.message_encoding,
                                schema_id=ids[key], metadata={}))
        both.append(channels[-1])
        out.append((topic, schema, codec))
    return schemas, channels, both, out


def _write_log_reference(log: FieldLog, path, *, force: bool = False, chunk_size: int = 1 << 20,
                         compression: str = "zstd") -> None:
    """Write ``log`` through the mcap library's Writer, one ``add_message`` per message, in
    :func:`.writer.write_log`'s layout (the reference it is tested against): schema and
    channel records outside chunks; each channel's messages, in (time, row) order, in
    chunks of their own, one closed after the message that takes it past ``chunk_size``
    (message record bytes); the chunks so closed in order of (last message's time,
    channel id), then the channels' last chunks in that order."""
    # start-up: the mcap library loads only for the reference paths
    from mcap.writer import CompressionType, Writer

    comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
            "none": CompressionType.NONE}[_compression(compression)]
    _schemas, _channels, registered, encs = _schema_records(log)
    closed, last = [], []   # chunks: (last time, channel id, [(time, row, payload)])
    for cid, (topic, _schema, codec) in enumerate(encs, start=1):
        frame = log.channels[topic]
        t = np.asarray(frame.index, dtype=np.int64)
        if len(t) and t.min() < 0:
            raise InputError(f"channel {topic}: negative time stamp at row {int(np.argmin(t))}")
        payloads = codec.encode_reference(frame, topic)
        chunk, size = [], 0
        for r in np.argsort(t, kind="stable").tolist():
            chunk.append((int(t[r]), r, payloads[r]))
            size += 31 + len(payloads[r])   # a Message record: 9 + 22 bytes before the payload
            if size > chunk_size:
                closed.append((chunk[-1][0], cid, chunk))
                chunk, size = [], 0
        if chunk:
            last.append((chunk[-1][0], cid, chunk))
    with atomic_path(path, force=force) as tmp:
        with open(tmp, "wb") as fh:
            w = Writer(fh, chunk_size=1 << 62, compression=comp, enable_data_crcs=True)
            w.start(profile="", library=f"usvlog {__version__}")
            for name in sorted(log.meta):
                w.add_metadata(name, {str(k): str(v) for k, v in log.meta[name].items()})
            # the library puts schema and channel records into its open chunk: with its chunk
            # builder set aside they go outside chunks
            builder, w._Writer__chunk_builder = w._Writer__chunk_builder, None
            for r in registered:
                if hasattr(r, "topic"):
                    w.register_channel(topic=r.topic, message_encoding=r.message_encoding, schema_id=r.schema_id)
                else:
                    w.register_schema(name=r.name, encoding=r.encoding, data=r.data)
            w._Writer__chunk_builder = builder
            for _t, cid, chunk in sorted(closed, key=lambda c: c[:2]) + sorted(last, key=lambda c: c[:2]):
                for t_i, r_i, data in chunk:
                    w.add_message(channel_id=cid, log_time=t_i, data=data, publish_time=t_i, sequence=r_i)
                w.flush()
            w.finish()


def _scan_reference(data: bytes) -> _Scan:
    """The plain reading of the records (one Python step per record), kept as the
    reference the fast scan is tested against: the same checks, the same
    resynchronisation after damage, the same report."""
    scan = _Scan()
    _layout(scan, data)
    buf = memoryview(data)
    end, off = scan.data_end, 8
    checked: dict[int, str | None] = {}

    def verify(o: int) -> str | None:
        if o not in checked:
            why = None
            ln = _chunk_shape(data, o, end)
            if ln < 0:
                why = "no consistent chunk header"
            else:
                try:
                    chunk = memoryview(_chunk_data(buf, o + 9, o + 9 + ln)[2])
                    for op, b, e in _chunk_records(chunk):
                        try:
                            _parse(op, chunk[b:e])
                        except (struct.error, UnicodeDecodeError, IndexError) as err:
                            raise _CorruptChunk(f"a record in it does not parse: {err}") from err
                except _CorruptChunk as err:
                    why = str(err)
            checked[o] = why
        return checked[o]

    while True:
        why, cut = None, False
        if off + 9 > end:
            cut = True
        else:
            op, length = _REC.unpack_from(buf, off)
            body, nxt = off + 9, off + 9 + length
            if nxt > end:
                cut = True
            else:
                why = _unexpected(scan, op, off, length)
        if not cut and why is None:
            try:
                if op == OP_MESSAGE:
                    _add_message(scan, buf, body, nxt)
                elif op == OP_CHUNK:
                    chunk = memoryview(_chunk_data(buf, body, nxt)[2])
                    recs = _chunk_records(chunk)
                    try:
                        parsed = [(o, b, e, _parse(o, chunk[b:e])) for o, b, e in recs]
                    except (struct.error, UnicodeDecodeError, IndexError) as err:
                        raise _CorruptChunk(f"a record in it does not parse: {err}") from err
                    for o, b, e, pr in parsed:
                        if o == OP_MESSAGE:
                            _add_message(scan, chunk, b, e)
                        elif pr is not None:
                            _apply(scan, pr, True)
                elif op == OP_MESSAGE_INDEX:
                    _check_message_index(buf, body, length)
                else:
                    pr = _parse(op, buf[body:nxt])
                    if pr is not None:
                        _apply(scan, pr, False)
            except _CorruptChunk as err:
                why = f"chunk at byte {off} is corrupt ({err})"
            except (struct.error, UnicodeDecodeError, IndexError) as err:
                why = f"malformed record at byte {off} ({err})"
            if why is None:
                if op == OP_DATA_END:
                    scan.data_end_at = off
                if op in (OP_FOOTER, OP_DATA_END):
                    break  # the data section is complete; the summary is not needed for reading
                off = nxt
                continue
        if cut and scan.footer and off == end:
            break
        resume = _resync(scan, off, verify, lambda p: _next_chunk_reference(data, p, end))
        _note_region(scan, data, off, end if resume is None else resume,
                     why or _region_reason(scan, off, resume is not None), verify)
        if resume is None:
            break
        off = resume

    _finish(scan, data)
    # messages on a channel not defined before them: kept when the channel's only
    # definition was lost and the summary still has it
    pending, scan.orphans = scan.orphans, {}
    for cid, msgs in pending.items():
        if cid in scan.channels:
            continue
        ch = _summary_channel(scan, cid)
        if ch is None:
            scan.orphans[cid] = len(msgs)
            continue
        scan.channels[cid] = ch
        for t, seq, payload in msgs:
            ch.times.append(t)
            ch.seqs.append(seq)
            ch.payloads.append(payload)
    return scan


def read_log_reference(path, *, topics=None, strict=False) -> FieldLog:
    """:func:`usvlog.io.mcap.read_log` through the plain scan (the reference the tests compare with)."""
    return _read_log(path, topics=topics, strict=strict, scanner=_scan_reference)
