"""MCAP record layout shared by the writer and the readers: magic, opcodes, fixed structs."""

import struct
import zlib

try:   # CRC-32 (zlib's polynomial) at ~10 GB/s, zlib's ~1.3 GB/s; zlib's when fastcrc is missing
    from fastcrc.crc32 import iso_hdlc as crc32
except ImportError:  # pragma: no cover - fastcrc is a dependency
    crc32 = zlib.crc32

MAGIC = b"\x89MCAP0\r\n"

OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
OP_METADATA, OP_DATA_END = 0x0C, 0x0F
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_METADATA_INDEX = 0x07, 0x08, 0x0D
OP_STATISTICS = 0x0B

# a chunk record's body without its compression name and data: start/end time, uncompressed
# size, CRC, name length, data length (bytes)
CHUNK_FIXED = 8 + 8 + 8 + 4 + 4 + 8
COMPRESSIONS = (b"", b"lz4", b"zstd")

_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_REC = struct.Struct("<BQ")
_MSG = struct.Struct("<HIQQ")
_CHUNK = struct.Struct("<QQQI")
_FOOTER = struct.Struct("<BQQQI")  # opcode, length 20, summary start, summary offset start, CRC
