"""Frames simulated a time window at a time, put together (tests of the windowed simulations)."""

import pandas as pd


def joined(windows) -> tuple[int, dict[str, pd.DataFrame]]:
    """The number of windows, and topic -> the windows' frames of it concatenated (in the order
    the topics first come)."""
    parts: dict[str, list] = {}
    n = 0
    for frames in windows:
        n += 1
        for topic, f in frames.items():
            parts.setdefault(topic, []).append(f)
    return n, {topic: pd.concat([f for f in fs if len(f)]) for topic, fs in parts.items()}
