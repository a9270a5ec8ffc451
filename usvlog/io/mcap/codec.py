"""The message codecs of canonical channels: which codec a channel is written and read with.

Two codecs turn frames into messages and back, for one schema each:

- :class:`Codec` (:mod:`.json_codec`, with the compiled decoding of :mod:`.json_layout`):
  flat JSON messages with a JSON Schema, the default;
- :class:`CdrCodec` (:mod:`.cdr`): little-endian CDR messages with a ``ros2msg`` schema, for
  the high-rate derived channels (:data:`usvlog.log.channels.BULK_TOPICS`).

The columns and their kinds come from the schema registry (:mod:`usvlog.log.channels`),
which knows nothing of these codecs. Decoding uses the schema stored *in the file*, so a
log stays readable after the registry changes; encoding uses the registry.
:func:`writer_codec` picks the codec a channel is written with, :func:`loadable` and
:func:`channel_codec` the one a channel read from a file is decoded with (by its
encodings). This module also names the codecs' public API, so ``from .codec import ...``
reaches all of it.
"""

from __future__ import annotations

import json
from functools import lru_cache

from ...log.channels import (
    BULK_TOPICS,
    CDR_MESSAGE_ENCODING,
    CDR_SCHEMA_ENCODING,
    MESSAGE_ENCODING,
    SCHEMA_ENCODING,
    schema_for_topic,
)
from .cdr import ROS2MSG_PACKAGE, CdrCodec, _cdr_schema, cdr_codec
from .json_codec import Codec, codec_for_schema, codec_for_topic

__all__ = ["CdrCodec", "Codec", "cdr_codec", "channel_codec", "codec_for_schema", "codec_for_topic",
           "writer_codec"]


def writer_codec(topic: str, schema: dict) -> Codec:
    """The codec a channel is written with: CDR for the bulk derived channels
    (:data:`usvlog.log.channels.BULK_TOPICS`) whose schema allows it, else JSON."""
    if topic in BULK_TOPICS:
        c = cdr_codec(schema)
        if c is not None:
            return c
    return codec_for_topic(topic) or codec_for_schema(schema)


def loadable(message_encoding: str, schema_encoding: str, schema_name: str) -> bool:
    """Whether :func:`usvlog.io.mcap.read_log` loads a channel of these encodings: JSON with a
    JSON Schema, or CDR with a ros2msg schema usvlog wrote (``usvlog/msg/...``)."""
    if message_encoding == MESSAGE_ENCODING and schema_encoding == SCHEMA_ENCODING:
        return True
    return (message_encoding == CDR_MESSAGE_ENCODING and schema_encoding == CDR_SCHEMA_ENCODING
            and schema_name.startswith(ROS2MSG_PACKAGE))


def channel_codec(topic: str, message_encoding: str, schema_encoding: str, schema_name: str,
                  schema_data: bytes) -> tuple[dict, Codec]:
    """(JSON Schema, codec) of a channel as stored in a file (see :func:`loadable`).

    A JSON channel's codec is its stored JSON Schema's. A CDR channel's is its topic's
    registered schema when that gives the same ros2msg fields (the frame's columns as
    registered), else one made from the ros2msg definition (a column per field).

    Raises
    ------
    ValueError, TypeError
        The stored schema is not usable.
    """
    if message_encoding == CDR_MESSAGE_ENCODING:
        schema, codec = _cdr_channel(topic, schema_name, schema_data.decode("utf-8"))
        return json.loads(json.dumps(schema)), codec   # the caller's own copy (the registry's is cached)
    schema = json.loads(schema_data) if schema_data else {"title": schema_name, "properties": {}}
    if not isinstance(schema, dict):
        raise TypeError("not an object")
    return schema, codec_for_schema(schema)


@lru_cache(maxsize=256)
def _cdr_channel(topic: str, schema_name: str, msgdef: str) -> tuple[dict, CdrCodec]:
    synth = _cdr_schema(schema_name, msgdef)
    registered = schema_for_topic(topic)
    if registered is not None:
        c = cdr_codec(registered)
        if c is not None and _cdr_schema(schema_name, c.msgdef) == synth:
            return registered, c
    c = cdr_codec(synth)
    if c is None:
        raise ValueError(f"ros2msg {schema_name} has no usable field")
    return synth, c
