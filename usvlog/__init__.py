"""usvlog: field logs of small unmanned surface vessels -> estimates, models, replays."""

__version__ = "0.1.0"

from .errors import UsvlogError  # noqa: E402
from .log.fieldlog import FieldLog  # noqa: E402


def load(path, **kwargs) -> FieldLog:
    """Load a canonical MCAP log (recovering what it can from a damaged file); a list of
    paths loads consecutive files of one run (a rotated recording) as one log."""
    from .io.mcap import read_log, read_logs

    if isinstance(path, (list, tuple)):
        return read_logs(path, **kwargs)
    return read_log(path, **kwargs)


__all__ = ["FieldLog", "UsvlogError", "load", "__version__"]
