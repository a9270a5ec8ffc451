import pytest

from usvlog.io.mcap import write_log
from usvlog.sim.simulate import SimSettings, simulate


@pytest.fixture(scope="session")
def excitation_log():
    """A 120 s seeded excitation run (in memory)."""
    return simulate("excitation", SimSettings(duration_s=120.0), seed=3)


@pytest.fixture(scope="session")
def excitation_file(tmp_path_factory, excitation_log):
    path = tmp_path_factory.mktemp("logs") / "excitation.mcap"
    write_log(excitation_log, path)
    return path
