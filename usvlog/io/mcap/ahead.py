"""Reading ahead on a second thread: an iterator's items produced by a thread while the caller works.

The MCAP reads' walks (zstd decompression, the CRC, the compiled record walks: all release
the GIL) run ahead of the code that decodes or copies what they yield.
"""

from __future__ import annotations

READ_AHEAD = 2     # batches (a chunk each: decompressed, CRC-checked, walked) read ahead by default


class ReadAhead:
    """The items of iterator ``it``, produced by a thread up to ``depth`` ahead of the
    caller (zstd decompression, the CRC and the compiled walks release the GIL: a file's
    chunks are unpacked on another core while the caller decodes, encodes or copies them).
    An exception of ``it`` is raised by the :func:`next` that would have returned its item;
    :meth:`close` stops the thread (it must be called before the source ``it`` reads is
    closed)."""

    _END = object()

    def __init__(self, it, depth: int = READ_AHEAD):
        import queue
        import threading

        self._q: queue.Queue = queue.Queue(depth)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(it,), name="usvlog-mcap-read", daemon=True)
        self._thread.start()

    def _run(self, it) -> None:
        try:
            for item in it:
                self._q.put((item, None))
                if self._stop.is_set():
                    return
            self._q.put((self._END, None))
        except BaseException as err:  # noqa: BLE001 - handed to the caller's next()
            self._q.put((None, err))

    def __iter__(self):
        return self

    def __next__(self):
        item, err = self._q.get()
        if err is not None:
            self._stop.set()
            raise err
        if item is self._END:
            self._stop.set()
            raise StopIteration
        return item

    def close(self) -> None:
        """Stop the thread (waits for the item it is producing) and drop what it read."""
        import queue

        self._stop.set()
        while self._thread.is_alive():
            try:   # make room: the thread may be waiting to put an item
                self._q.get(timeout=0.05)
            except queue.Empty:
                pass
        self._thread.join()
