"""What a channel is written with: its schema and codec, and its MCAP Schema record.

Shared by the writer (:class:`usvlog.io.mcap.file_writer.McapWriter` registers each
channel with them; :func:`usvlog.io.mcap.writer.write_log` decides with them whether a
deferred channel can be copied as stored) and by the reference path (:mod:`.reference`).
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

from ...errors import InputError
from ...log.channels import (
    SCHEMA_ENCODING,
    auto_schema,
    schema_for_topic,
)
from .codec import Codec, writer_codec

if TYPE_CHECKING:   # pandas is imported where a frame is made (inspect never needs it)
    import pandas as pd


def _codec_for(topic: str, schema: dict | None = None, frame: pd.DataFrame | None = None) -> tuple[dict, Codec]:
    """(schema, codec) of a channel: the registered schema, else ``schema`` (e.g. the one
    stored in the file read), else one generated from ``frame``'s dtypes; the codec is
    CDR for the bulk derived channels, else JSON (:func:`.codec.writer_codec`)."""
    schema = schema_for_topic(topic) or schema
    if schema is None:
        if frame is None:
            raise InputError(f"channel {topic}: no registered schema (see schemas/)")
        schema = auto_schema(topic, frame)
    return schema, writer_codec(topic, schema)


def _schema_record(topic: str, schema: dict, codec: Codec) -> tuple[str, str, bytes]:
    """(name, encoding, data) of a channel's Schema record: the JSON Schema (named by its
    title), or the ros2msg definition of a CDR channel."""
    if codec.schema_encoding == SCHEMA_ENCODING:
        return schema.get("title", topic), SCHEMA_ENCODING, json.dumps(schema, sort_keys=False).encode()
    return codec.schema_name, codec.schema_encoding, codec.schema_data


def _compression(compression: str) -> str:
    if compression not in ("zstd", "lz4", "none"):
        raise InputError(f"unknown compression {compression!r} (zstd, lz4 or none)")
    return compression
