"""What a new user runs into: every mistake is one line on stderr and exit 2, nothing written."""

import shutil

import pytest

from usvlog.cli import main
from usvlog.resources import replay_dir


def _one_line_error(capsys, *words):
    """The error is the last line on stderr and the only one saying error (progress lines may precede it)."""
    err = capsys.readouterr().err.strip().splitlines()
    assert [x for x in err if "error" in x] == err[-1:], err
    assert not any("Traceback" in x for x in err)
    for w in words:
        assert w in err[-1], err[-1]
    return err[-1]


@pytest.mark.parametrize("argv, words", [
    (["identify", "a.mcap", "--out", "p.toml", "--method", "foo"], ["usvlog identify: error", "'foo'", "--help"]),
    (["estimate", "a.mcap", "--out", "e.mcap", "--model", "foo"], ["usvlog estimate: error", "kinematic"]),
    (["export", "a.mcap", "--out", "d", "--format", "xyz"], ["usvlog export: error", "parquet"]),
    (["replay", "a.mcap", "--out", "r.mcap"], ["usvlog replay: error", "--scenario"]),
    (["nosuchverb"], ["usvlog: error", "invalid choice"]),
])
def test_usage_errors_are_one_line(argv, words, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    _one_line_error(capsys, *words)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("fix, words", [("m=-3", "m must be > 0"), ("Iz=0", "Iz must be > 0"),
                                        ("d22=-1", "d22 must be >= 0"), ("xg=nan", "xg must be finite")])
def test_identify_rejects_impossible_fix(fix, words, excitation_file, tmp_path, capsys):
    out = tmp_path / "p.toml"
    assert main(["identify", str(excitation_file), "--out", str(out), "--fix", fix]) == 2
    _one_line_error(capsys, f"--fix '{fix}'", words)
    assert not out.exists()


def test_report_into_unwritable_place_is_a_user_error(excitation_file, tmp_path, capsys):
    blocker = tmp_path / "file.txt"
    blocker.write_text("not a directory")
    assert main(["report", str(excitation_file), "--out", str(blocker / "rep")]) == 2
    _one_line_error(capsys, "file.txt/rep", "cannot create directory")


def test_gains_default_is_the_paper_section_iv(capsys):
    # the paper's Section IV: m = 33, Iz = 10, d = 5, xg = 0.1; KPu = 5, KIu = 0.5, KPpsi = 5, KIpsi = 0.1, KDpsi = 1
    assert main(["gains"]) == 0
    out = capsys.readouterr().out
    assert "m=33 Iz=10 d11=5 d22=5 d33=5 xg=0.1" in out
    assert "KPu=5 KIu=0.5 KPpsi=5 KIpsi=0.1 KDpsi=1" in out
    assert main(["gains", "--gains", "paper-sine"]) == 0
    assert "KPpsi=" in capsys.readouterr().out
    assert main(["gains", "--gains", "nosuch"]) == 2
    _one_line_error(capsys, "'nosuch'", "paper-circle")


def test_unknown_simulate_scenario_lists_every_kind(tmp_path, capsys):
    out = tmp_path / "x.mcap"
    assert main(["simulate", "xyz", "--out", str(out)]) == 2
    line = _one_line_error(capsys, "'xyz'", "excitation", "turns", "straight", "paper-circle", "paper-sine")
    assert "ident-current" not in line  # a regression scenario, not something simulate runs
    assert not out.exists()


def test_regression_scenario_given_to_simulate_or_replay(tmp_path, capsys, excitation_file):
    assert main(["simulate", "ident-current", "--out", str(tmp_path / "x.mcap")]) == 2
    _one_line_error(capsys, "regression scenario", "usvlog regress")
    assert main(["replay", str(excitation_file), "--scenario", "ident-current", "--out",
                 str(tmp_path / "r.mcap")]) == 2
    _one_line_error(capsys, "regression scenario", "usvlog regress")
    assert not list(tmp_path.iterdir())


def test_regress_missing_dataset_is_one_line_before_any_work(tmp_path, capsys):
    shutil.copy(replay_dir() / "ident-current.toml", tmp_path / "ident-current.toml")  # ../tests/data/... is absent
    junit = tmp_path / "junit.xml"
    assert main(["regress", str(tmp_path), "--junit", str(junit)]) == 2
    _one_line_error(capsys, "ident-current.mcap", "not found", "1 of 1")
    assert not junit.exists()


def test_interrupted_report_writes_nothing(tmp_path, monkeypatch):
    from usvlog.sim.closed_loop import simulate_scenario
    from usvlog.sim.scenario import load_scenario
    from usvlog.view import report

    log = simulate_scenario(load_scenario("paper-circle"), duration_s=20.0)

    def ctrl_c(*a, **k):  # Ctrl-C while the fourth figure renders
        raise KeyboardInterrupt

    monkeypatch.setattr(report, "_fig_speed_heading", ctrl_c)
    with pytest.raises(KeyboardInterrupt):
        report.write_report(log, tmp_path / "rep")
    assert not (tmp_path / "rep").exists()
    monkeypatch.undo()
    page = report.write_report(log, tmp_path / "rep")
    names = sorted(p.name for p in page.parent.iterdir())
    assert names == ["fig1_track.png", "fig2_errors.png", "fig5_speed_heading.png", "report.html"]  # no Fig. 4
    assert all((page.parent / n).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for n in names if n.endswith(".png"))


def test_ctrl_c_inside_compiled_code_is_an_interruption():
    from usvlog.cli import interrupted

    try:  # what numba's dispatcher raises when Ctrl-C lands inside a compiled call
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            # chained implicitly (no `from`), as numba's dispatcher does
            raise SystemError("CPUDispatcher(<function f>) returned a result with an exception set")  # noqa: B904
    except SystemError as err:
        assert interrupted(err)
    assert not interrupted(SystemError("a real bug"))
    assert not interrupted(ValueError("x"))


def test_export_refuses_before_writing_any_file(excitation_file, tmp_path, capsys):
    out = tmp_path / "csv"
    out.mkdir()
    (out / "truth__state.csv").write_text("mine\n")  # the last channel's file exists, the others do not
    assert main(["export", str(excitation_file), "--out", str(out)]) == 2
    _one_line_error(capsys, "truth__state.csv", "output exists")
    assert sorted(p.name for p in out.iterdir()) == ["truth__state.csv"]
    assert (out / "truth__state.csv").read_text() == "mine\n"


@pytest.mark.parametrize("port", ["0", "99999", "-1"])
def test_view_bad_port_refused_before_any_work(port, excitation_file, tmp_path, capsys):
    out = tmp_path / "x.rrd"
    assert main(["view", str(excitation_file), "--out", str(out), "--serve", "--port", port]) == 2
    _one_line_error(capsys, f"--port {port}", "65535")
    assert not out.exists()


def test_demo_bad_output_or_duration_is_a_user_error(tmp_path, capsys):
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    assert main(["demo", "--out", str(blocker)]) == 2
    _one_line_error(capsys, "file.txt", "not a directory")
    assert main(["demo", "--out", str(blocker / "sub")]) == 2
    _one_line_error(capsys, "file.txt/sub", "cannot create directory")
    assert main(["demo", "--out", str(tmp_path / "d"), "--duration-s", "-1"]) == 2
    _one_line_error(capsys, "duration_s = -1.0", "> 0")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.txt"]


def test_regress_junit_place_checked_before_running(tmp_path, capsys):
    junit = tmp_path / "nodir" / "junit.xml"
    assert main(["regress", str(replay_dir() / "ident-current.toml"), "--junit", str(junit)]) == 2
    _one_line_error(capsys, "junit.xml", "does not exist")
    assert main(["regress", str(replay_dir() / "ident-current.toml"), "--junit", str(tmp_path)]) == 2
    _one_line_error(capsys, "output is a directory")


@pytest.mark.parametrize("argv", [
    ["estimate", "{log}", "--out", "{nodir}/e.mcap"],
    ["identify", "{log}", "--out", "{nodir}/p.toml"],
    ["identify", "{log}", "--out", "{tmp}/p.toml", "--out-log", "{nodir}/fit.mcap"],
    ["replay", "{log}", "--scenario", "paper-circle", "--out", "{nodir}/r.mcap"],
    ["simulate", "excitation", "--out", "{nodir}/s.mcap"],
    ["view", "{log}", "--out", "{nodir}/v.rrd"],
])
def test_output_in_a_missing_directory_fails_before_the_work(argv, excitation_file, tmp_path, capsys):
    fill = {"log": str(excitation_file), "nodir": str(tmp_path / "nodir"), "tmp": str(tmp_path)}
    assert main([a.format(**fill) for a in argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nodir" in err[0] and "does not exist" in err[0], err  # refused before any progress
    assert not list(tmp_path.iterdir())  # and no other output written either
