"""Channels the recorder writes besides the canonical sensor topics, and its metadata name."""

from __future__ import annotations

TOPIC_FIX = "/gnss/fix"
TOPIC_QUALITY = "/gnss/quality"
TOPIC_HEADING = "/compass/heading"
TOPIC_THRUST = "/thrust/command"
TOPIC_RAW_NMEA = "/raw/nmea"
TOPIC_RAW_JSON = "/raw/json"
TOPIC_EVENTS = "/events"
TOPIC_STATUS = "/recorder/status"
META_RECORDING = "usvlog.recording"   # {run_id, part, started_utc}: lets read_logs check consecutive files
