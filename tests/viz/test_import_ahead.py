"""view and report import the Rerun SDK / matplotlib on a second thread while the log is read
(:func:`usvlog.view.source.import_ahead`): when that import fails, the user gets the same
messages and exit code as when it runs on the main thread (USVLOG_THREADS=1), and no output."""

import subprocess
import sys
from pathlib import Path

DATA = Path(__file__).resolve().parents[1] / "data"

SCRIPT = """
import io, os, sys, contextlib
sys.modules["rerun"] = sys.modules["matplotlib"] = None     # the modules imported ahead cannot be imported
from usvlog.cli import main
log, out = sys.argv[1:]
got = []
for argv in (["view", log, "--out", out + "/e.rrd"], ["report", log, "--out", out + "/report"]):
    for threads in ("1", "2"):
        os.environ["USVLOG_THREADS"] = threads
        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            try:
                code = main(argv)
            except SystemExit as e:
                code = e.code
        got.append((code, err.getvalue()))
print(repr(got))
"""


def test_a_failed_import_ahead_reaches_the_user_as_on_one_thread(tmp_path):
    r = subprocess.run([sys.executable, "-c", SCRIPT, str(DATA / "gps-faults.mcap"), str(tmp_path)],
                       capture_output=True, text=True, check=True)
    view1, view2, report1, report2 = eval(r.stdout.strip().splitlines()[-1])   # noqa: S307 - our own repr
    assert view1 == view2 and view1[0] == 3 and "rerun" in view1[1]        # an internal error: the SDK is core
    assert report1 == report2 and report1[0] == 2 and "matplotlib" in report1[1]   # an optional extra: a user error
    assert not (tmp_path / "e.rrd").exists() and not (tmp_path / "report" / "report.html").exists()
